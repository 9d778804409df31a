"""Where an integration step's kernel calls come from, by source line.

On a CPU a step of ``simulate`` costs about its kernel calls (XLA's thunks: fusions, copies,
loops, conditionals) times a few tens of ns each, so the count per step is what a change to
the hot path moves, and unlike a time it is the same on every run of the same program. This
counts them (profiler traces of warm runs to t1 and 2 t1, the difference over the difference
in steps, ``bench_friction.kernel_calls``) and attributes each to the source line it
was traced from (the stack frames XLA keeps with every instruction of its optimized program):
the innermost line of this package (and the library, where the call is made in one), and the
area of the package its stack passes through (kinetostatics, friction law and solve,
kinematics, reduction and loads, the vector field; else diffrax's step, the events and the
outputs). A fusion is named after its root, so each call is attributed to its last operation.

The bundled press (``press_with_friction``) without and with its four friction elements, each
in a process of its own (XLA reads its dump flag once per process).

    python benchmarks/bench_step_calls.py      # writes results/step_calls.json
"""

from __future__ import annotations

import argparse
import collections
import glob
import json
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

HERE = os.path.dirname(os.path.abspath(__file__))
TOP_LINES = 30
# areas of the package, by the modules a call's stack passes through (the first area that any
# of its frames lies in: the statics' geometry counts as statics, a friction rate's as friction)
AREAS = (("kinetostatics", ("_kinetostatics/",)), ("friction", ("_friction.py",)),
         ("kinematics", ("_positions.py", "_kinematics.py", "groups/", "_tracking.py")),
         ("reduction and loads", ("_reduction.py", "_loads.py")), ("vector field", ("dynamics/_field.py",)))


def _stack_tables(lines):
    """The optimized module's stack-frame tables: frame id -> (file, line, function, parent id)."""
    section, files, functions, locations, frames = None, {}, {}, {}, {}
    for line in lines:
        if line in ("FileNames", "FunctionNames", "FileLocations", "StackFrames"):
            section = line
            continue
        match = re.match(r"^(\d+) (.*)$", line)
        if not (section and match):
            section = None if line.strip() else section
            continue
        key, rest = int(match.group(1)), match.group(2)
        if section == "FileNames":
            files[key] = rest.strip('"')
        elif section == "FunctionNames":
            functions[key] = rest.strip('"')
        elif section == "FileLocations":
            locations[key] = tuple(map(int, re.search(r"file_name_id=(\d+) function_name_id=(\d+) line=(\d+)", rest).groups()))
        else:
            location, parent = map(int, re.search(r"file_location_id=(\d+) parent_frame_id=(\d+)", rest).groups())
            file_id, function_id, number = locations[location]
            # a parent is named by its id + 1; a root names itself (the chain stops at a frame seen)
            frames[key] = (files[file_id], number, functions[function_id], parent - 1)
    return frames


def _chain(frames, frame):
    """(file, line, function) from the innermost frame outwards."""
    out, seen = [], set()
    while frame in frames and frame not in seen:
        seen.add(frame)
        path, number, function, parent = frames[frame]
        out.append((path, number, function))
        frame = parent
    return out


def _where(chain):
    """(the innermost source line of this package, or the library the call comes from; its area)."""
    ours = [(path.split("assurjax/", 1)[1], number, function) for path, number, function in chain if "/assurjax/" in path]
    area = next((name for name, parts in AREAS if any(p in path for path, _, _ in ours for p in parts)), None)
    if area is None:
        area = "solver, events, outputs" if chain else "no source (copies, loop plumbing)"
    if not ours:
        return "[no source]" if not chain else f"[{_library(chain[0][0])}]", area
    path, number, function = ours[0]
    line = f"{path}:{number} ({function})"
    return (line if "/assurjax/" in chain[0][0] else f"[{_library(chain[0][0])}] from {line}"), area


def _library(path):
    return path.split("site-packages/")[-1].split("/")[0]


def _calls_per_step(scene, loads, t1):
    """Per-step kernel calls by instruction name, from warm runs to t1 and 2 t1."""
    from bench_friction import kernel_calls

    (n_short, short), (n_long, long) = (kernel_calls(scene, loads, t) for t in (t1, 2 * t1))
    return {name: (long[name] - short[name]) / (n_long - n_short) for name in long if long[name] != short[name]}


def measure(variant: str, dump: str) -> dict:
    """One variant, in a process whose XLA dumps its optimized programs to ``dump``."""
    import assurjax

    press = assurjax.load_scene("press_with_friction")
    loads = press.loads if variant == "friction" else tuple(load for load in press.loads if not load.needs_reactions)
    per_name = _calls_per_step(press, loads, t1=0.2)
    (module,) = glob.glob(os.path.join(dump, "*_integrate*after_optimizations.txt"))
    with open(module) as f:
        lines = f.read().splitlines()
    frames = _stack_tables(lines)
    frame_of = {}
    for line in lines:
        match = re.match(r"\s*(?:ROOT )?%([\w.\-]+) = .*stack_frame_id=(\d+)", line)
        if match:
            frame_of[match.group(1)] = int(match.group(2))
    by_line, by_area = collections.Counter(), collections.Counter()
    for name, calls in per_name.items():
        line, area = _where(_chain(frames, frame_of.get(name, -1)))
        by_line[line] += calls
        by_area[area] += calls
    return dict(calls_per_step=sum(per_name.values()), by_area=dict(by_area.most_common()),
                top_lines=dict(by_line.most_common(TOP_LINES)))


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=os.path.join(HERE, "results", "step_calls.json"))
    parser.add_argument("--variant", choices=("plain", "friction"), help=argparse.SUPPRESS)  # one process's share
    parser.add_argument("--dump", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.variant:
        print(json.dumps(measure(args.variant, args.dump)))
        return
    out = dict(scene="press_with_friction", variants={})
    for variant in ("plain", "friction"):
        with tempfile.TemporaryDirectory() as dump:
            flags = f"--xla_dump_to={dump} --xla_dump_hlo_as_text --xla_dump_hlo_module_re=.*_integrate.*"
            env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} {flags}".strip())
            run = subprocess.run([sys.executable, __file__, "--variant", variant, "--dump", dump], env=env,
                                 capture_output=True, text=True)
        if run.returncode != 0:
            raise SystemExit(f"the {variant} run failed:\n{run.stderr}")
        out["variants"][variant] = result = json.loads(run.stdout.strip().splitlines()[-1])
        print(variant, json.dumps(dict(calls_per_step=result["calls_per_step"], by_area=result["by_area"]), indent=1))
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
