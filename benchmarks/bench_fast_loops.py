"""``assurjax.enable_fast_loops()``: what XLA compiling each integration loop into one
function gains and costs, through the user's call ``assurjax.simulate``.

Each configuration runs in a fresh process (the XLA flag is read once per process), with
no persistent compilation cache: the first call (trace and compile) and the best warm
call of single simulations on the bundled scenes, with and without joint friction in every
pair; a batch of 16 starts; the marginal cost of one more step of the driven press (runs
of 2 and 4 s, as in bench_friction.py); and whether the integration program still calls
LAPACK with friction (then XLA cannot compile its loop into one function), for the press
and the triad mechanism.

    python benchmarks/bench_fast_loops.py          # writes results/fast_loops.json
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))

# (scene, t1, friction in every pair)
SINGLE = [("slider_crank", 2.0, False), ("slider_crank", 2.0, True), ("watt_sixbar", 2.0, False),
          ("watt_sixbar", 2.0, True), ("press_with_friction", 2.0, False), ("press_with_friction", 2.0, True),
          ("quick_return", 2.0, False), ("triad_mechanism", 2.0, False), ("triad_mechanism", 1.0, True),
          ("strandbeest", 0.2, False)]

CHILD = r"""
import json, sys, time
sys.path.insert(0, {here!r})
import assurjax
if {fast}:
    assurjax.enable_fast_loops()
import numpy as np
from _timing import best_time
from bench_friction import frictions, marginal_per_step

def loads_of(scene, rough):
    plain = tuple(l for l in scene.loads if not l.needs_reactions)
    if not rough:
        return plain
    return scene.loads if len(plain) < len(scene.loads) else plain + frictions(scene.mechanism)

def single(name, t1, rough):
    scene = assurjax.load_scene(name)
    kw = dict(loads=loads_of(scene, rough), t1=t1, stop=None, samples=201)
    start = time.perf_counter()
    sol = assurjax.simulate(scene, **kw)
    first = time.perf_counter() - start
    warm = best_time(lambda: assurjax.simulate(scene, **kw).q, repeats=5)
    return dict(scene=name, friction=rough, first_call_s=first, warm_ms=1e3 * warm, steps=int(sol.num_steps),
                q_final=float(sol.q_final), status=sol.status)

out = dict(single=[single(*case) for case in {single_cases!r}])
press = assurjax.load_scene("press_with_friction")
plain = tuple(l for l in press.loads if not l.needs_reactions)
out["press_marginal"] = dict(plain=marginal_per_step(press, plain), friction=marginal_per_step(press, press.loads))
starts = np.linspace(0.0, 6.0, 16)
out["press_batch16"] = {{key: marginal_per_step(press, loads, t1=1.0, repeats=3, q0=starts, reduction="exact")
                        for key, loads in (("plain", plain), ("friction", press.loads))}}
print("RESULT" + json.dumps(out))
"""

LAPACK_CHILD = r"""
import sys
sys.path.insert(0, {here!r})
import assurjax
if {fast}:
    assurjax.enable_fast_loops()
from bench_friction import frictions
scene = assurjax.load_scene({name!r})
rough = scene.loads if any(l.needs_reactions for l in scene.loads) else scene.loads + frictions(scene.mechanism)
assurjax.simulate(scene, loads=rough, t1=0.1, stop=None, samples=2)
"""


def run_child(fast: bool) -> dict:
    code = CHILD.format(here=HERE, fast=fast, single_cases=SINGLE)
    env = {**{k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}, "ASSURJAX_NO_CACHE": "1"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    line = next(line for line in done.stdout.splitlines() if line.startswith("RESULT"))
    return json.loads(line[len("RESULT"):])


def lapack_calls(fast: bool, name: str) -> dict:
    """Library calls left in the integration program with friction (XLA's dump after optimization)."""
    with tempfile.TemporaryDirectory() as dump:
        flags = f"--xla_dump_to={dump} --xla_dump_hlo_as_text"
        env = {**{k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}, "ASSURJAX_NO_CACHE": "1", "XLA_FLAGS": flags}
        subprocess.run([sys.executable, "-c", LAPACK_CHILD.format(here=HERE, fast=fast, name=name)], env=env, check=True,
                       capture_output=True)
        text = "".join(open(os.path.join(dump, f)).read() for f in os.listdir(dump)
                       if "integrate" in f and f.endswith("cpu_after_optimizations.txt"))
    calls = re.findall(r'custom_call_target="([^"]+)"', text)
    return {target: calls.count(target) for target in sorted(set(calls))}


def main():
    out = dict(machine=dict(platform=platform.platform(), cpus=os.cpu_count()), configurations={})
    for fast in (False, True):
        key = "fast_loops" if fast else "default"
        out["configurations"][key] = run_child(fast)
        out["configurations"][key]["lapack_in_press_integration"] = lapack_calls(fast, "press_with_friction")
        out["configurations"][key]["lapack_in_triad_integration"] = lapack_calls(fast, "triad_mechanism")
        print(key, json.dumps(out["configurations"][key], indent=1))
    default, fast = out["configurations"]["default"], out["configurations"]["fast_loops"]
    for a, b in zip(default["single"], fast["single"]):
        print(f"{a['scene']:>20} friction={a['friction']!s:5}  first {a['first_call_s']:.2f} -> {b['first_call_s']:.2f} s,"
              f"  warm {a['warm_ms']:.2f} -> {b['warm_ms']:.2f} ms ({a['warm_ms'] / b['warm_ms']:.1f}x),"
              f"  steps {a['steps']} / {b['steps']},  q_final rel. diff {abs(a['q_final'] - b['q_final']) / max(1, abs(a['q_final'])):.1e}")
    for case in ("press_marginal", "press_batch16"):
        for config in (default, fast):
            plain, rough = config[case]["plain"]["us_per_step"], config[case]["friction"]["us_per_step"]
            print(f"{case}: plain {plain:.2f} us, friction {rough:.2f} us ({rough / plain:.2f}x)")
    os.makedirs(os.path.join(HERE, "results"), exist_ok=True)
    with open(os.path.join(HERE, "results", "fast_loops.json"), "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
