"""Run every benchmark, one after the other (each in its own process, so that
compile caches and memory do not leak between them), and print their tables.

    pip install ".[bench]"
    python benchmarks/run_all.py [--quick] [--only work_precision throughput ...]

Results: benchmarks/results/*.json (+ *.png); a summary of the run (each script's
wall time and exit status) in benchmarks/results/run_all.json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# name -> (script, extra arguments for --quick); scripts that are not there yet are skipped
BENCHMARKS = {
    "kinematics": ("bench_kinematics.py", ["--n", "10000", "--repeats", "3"]),
    "dynamics": ("bench_dynamics.py", ["--quick"]),
    "overhead": ("bench_overhead.py", ["--quick"]),
    "command": ("bench_command.py", ["--repeats", "1"]),
    "profile": ("bench_profile.py", []),
    "compile_options": ("bench_compile_options.py", []),
    "kinetostatics": ("bench_kinetostatics.py", ["--repeats", "3"]),
    "batched_statics": ("bench_batched_statics.py", ["--repeats", "1"]),
    "chunked_outputs": ("bench_chunked_outputs.py", ["--repeats", "1"]),
    "dyads": ("bench_dyads.py", ["--repeats", "3"]),
    "friction": ("bench_friction.py", []),
    "friction_first_calls": ("bench_friction_first_calls.py", ["--repeats", "1"]),
    "friction_step_parts": ("bench_friction_step_parts.py", ["--repeats", "1"]),
    "step_calls": ("bench_step_calls.py", []),
    "step_instructions": ("bench_step_instructions.py", []),
    "friction_precision": ("bench_friction_precision.py", ["--quick"]),
    "friction_gradients": ("bench_friction_gradients.py", ["--quick"]),
    "fast_loops": ("bench_fast_loops.py", []),
    "synthesis": ("bench_synthesis.py", ["--quick"]),
    "iterative": ("bench_iterative.py", ["--n", "10000", "--repeats", "2"]),
    "gradients": ("bench_gradients.py", ["--repeats", "3"]),
    "vmapped_paths": ("bench_vmapped_paths.py", ["--repeats", "1"]),
    "work_precision": ("bench_work_precision.py", ["--quick", "--repeats", "2"]),
    "throughput": ("bench_throughput.py", ["--max", "10000"]),
    "scaling": ("bench_scaling.py", ["--sizes", "1", "2", "5", "--repeats", "3"]),
    "float32": ("bench_float32.py", []),
}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller runs (a smoke test of every script)")
    parser.add_argument("--only", nargs="+", choices=sorted(BENCHMARKS), help="run only these")
    args = parser.parse_args()
    summary = {}
    for name, (script, quick_args) in BENCHMARKS.items():
        if args.only and name not in args.only:
            continue
        path = HERE / script
        if not path.exists():
            summary[name] = dict(status="missing", script=script)
            print(f"== {name}: {script} not found, skipped", flush=True)
            continue
        cmd = [sys.executable, str(path)] + (quick_args if args.quick else [])
        print(f"\n== {name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        code = subprocess.call(cmd, cwd=HERE)
        summary[name] = dict(status="ok" if code == 0 else f"exit code {code}", script=script, wall_s=time.perf_counter() - t0)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "run_all.json").write_text(json.dumps(summary, indent=1))
    print("\n== summary")
    for name, s in summary.items():
        print(f"  {name:15s} {s['status']:12s} {s.get('wall_s', 0.0):8.1f} s")
    sys.exit(0 if all(s["status"] in ("ok", "missing") for s in summary.values()) else 1)


if __name__ == "__main__":
    main()
