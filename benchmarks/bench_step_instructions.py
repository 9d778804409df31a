"""Instructions per integration step, counted by valgrind's callgrind: a cost that noise
does not move.

On a shared machine one more step of the press measures 35-55 us with friction over runs of
the same program (``bench_friction.py``), a spread larger than most changes to the hot path.
The CPU's instructions are nearly the same from run to run of the same program and inputs,
whatever else the machine does. This runs warm ``simulate()`` calls of the bundled press
(``press_with_friction``: motor, process force, friction in its four pairs) to t1 and 2 t1
under callgrind, counting only those calls (instrumentation switched on around them by
callgrind's client requests), and reports the difference over the difference in steps, without
and with friction, and where each step's instructions go: XLA's compiled kernels, its
runtime's dispatch of them (thunks), memory allocation (the runtime's generic kernel call
allocates its argument list: a fusion of more than 12 operands, or of several results), and
libm's trigonometry. Memory and cache effects, which a time also sees, are not counted.

Needs valgrind (callgrind, with its client-request header ``valgrind/callgrind.h``) and a C
compiler (``cc``): a small library of the client requests is compiled for the run. About
1.5 min, both variants side by side.

    python benchmarks/bench_step_instructions.py      # writes results/step_instructions.json
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
T1 = 1.0  # s of the press's motion; the second run goes to 2 T1

CLIENT_REQUESTS = r"""
#include <valgrind/callgrind.h>
void start(void) { CALLGRIND_START_INSTRUMENTATION; }
void stop(void) { CALLGRIND_STOP_INSTRUMENTATION; }
void zero(void) { CALLGRIND_ZERO_STATS; }
void dump(const char *label) { CALLGRIND_DUMP_STATS_AT(label); }
"""
# where a function's instructions go, by its name in callgrind's profile (first match)
CATEGORIES = (("compiled kernels", r"^\?\?\?:0x"), ("libm", r"libm\.so|sincos|atan2|s_sin"),
              ("allocation", r"malloc|free|operator new|operator delete|memmove|memcpy"),
              ("runtime dispatch", r"Thunk|Kernel"))


def child(variant: str, library: str) -> None:
    """Under callgrind: compile both runs, then count each warm run on its own (two dumps)."""
    import jax
    import numpy as np

    import assurjax

    requests = ctypes.CDLL(library)
    press = assurjax.load_scene("press_with_friction")
    loads = press.loads if variant == "friction" else tuple(load for load in press.loads if not load.needs_reactions)

    def run(t1):
        result = assurjax.simulate(press, loads=loads, stop=None, t1=t1, samples=2)
        jax.block_until_ready(result.q)
        return int(np.asarray(result.num_steps))

    steps = [run(T1), run(2 * T1)]
    requests.start()
    for t1 in (T1, 2 * T1):
        requests.zero()
        run(t1)
        requests.dump(f"t1={t1}".encode())
    requests.stop()
    print(json.dumps(dict(steps=steps)))


def categories(profile: str) -> dict:
    """Instructions of one dump by category (callgrind_annotate's per-function table)."""
    table = subprocess.run(["callgrind_annotate", profile], capture_output=True, text=True, check=True).stdout
    totals = dict.fromkeys([name for name, _ in CATEGORIES] + ["other"], 0)
    for line in table.splitlines():
        match = re.match(r"^\s*([\d,]+) \([\s\d.]+%\)\s+(.*)$", line)
        if not match or "PROGRAM TOTALS" in line:
            continue
        count, function = int(match.group(1).replace(",", "")), match.group(2)
        name = next((name for name, pattern in CATEGORIES if re.search(pattern, function)), "other")
        totals[name] += count
    return totals


def summary(profile: str) -> int:
    with open(profile) as f:
        return int(next(line.split()[1] for line in f if line.startswith("summary:")))


def measure(variant: str, library: str, folder: str) -> subprocess.Popen:
    out = os.path.join(folder, f"{variant}.out")
    command = ["valgrind", "--tool=callgrind", "--instr-atstart=no", "--dump-instr=no", f"--callgrind-out-file={out}",
               sys.executable, __file__, "--child", variant, "--library", library]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def per_step(variant: str, process: subprocess.Popen, folder: str) -> dict:
    stdout, stderr = process.communicate()
    if process.returncode != 0:
        raise SystemExit(f"the {variant} run failed:\n{stderr[-3000:]}")
    (short, n_short), (long, n_long) = zip(
        (summary(os.path.join(folder, f"{variant}.out.{k}")) for k in (1, 2)),
        json.loads(stdout.strip().splitlines()[-1])["steps"])
    by_category = [categories(os.path.join(folder, f"{variant}.out.{k}")) for k in (1, 2)]
    steps = n_long - n_short
    return dict(steps=[n_short, n_long], instructions=[short, long], per_step=(long - short) / steps,
                per_step_by_category={name: (by_category[1][name] - by_category[0][name]) / steps
                                      for name in by_category[0]})


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "step_instructions.json"))
    parser.add_argument("--child", choices=("plain", "friction"), help=argparse.SUPPRESS)
    parser.add_argument("--library", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.library)
        return
    for tool in ("valgrind", "callgrind_annotate", "cc"):
        if shutil.which(tool) is None:
            raise SystemExit(f"{tool} is not installed: this benchmark needs valgrind (callgrind) and a C compiler")
    with tempfile.TemporaryDirectory() as folder:
        source, library = os.path.join(folder, "requests.c"), os.path.join(folder, "requests.so")
        with open(source, "w") as f:
            f.write(CLIENT_REQUESTS)
        subprocess.run(["cc", "-shared", "-fPIC", "-O1", "-o", library, source], check=True)
        processes = {variant: measure(variant, library, folder) for variant in ("plain", "friction")}
        variants = {variant: per_step(variant, process, folder) for variant, process in processes.items()}
    out = dict(machine=platform.platform(), cpus=os.cpu_count(), scene="press_with_friction", t1=T1, variants=variants,
               ratio=variants["friction"]["per_step"] / variants["plain"]["per_step"])
    print(json.dumps(out, indent=1))
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
