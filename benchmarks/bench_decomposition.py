"""Speed of building mechanisms from a sketch.

1. Decomposition (Gruebler's count and the Assur decomposition) and the whole build
   (frames, local coordinates, modes, the explicit Mechanism) of a 40-group sketch: an
   N-four-bar chain (a crank and 40 RRR dyads) and a mixed chain of 40 groups (RRR, RRP,
   RPR, PRP dyads and triads in turn). Target: decomposition under 50 ms.
2. Compile time: building from a sketch must add none over the explicit form. Jansen's leg
   as a sketch scene and the same scene written in the explicit form (``explicit_toml``)
   give the same pytree structure; the first ``simulate`` of each (trace, compile, run) is
   timed in fresh processes, alternately.

    python benchmarks/bench_decomposition.py [--repeats 3]

Writes benchmarks/results/decomposition.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import assurjax
from assurjax.structure import Sketch, Slide, build, decompose, explicit_toml

RESULTS = Path(__file__).resolve().parent / "results"


def four_bar_chain(n: int) -> Sketch:
    """The N-four-bar: rockers O_i -> B_i (vertical, 1 m), couplers B_i -> B_i+1; rocker 0 is the crank."""
    joints = {f"O{i}": (float(i), 0.0) for i in range(n + 1)} | {f"B{i}": (float(i), 1.0) for i in range(n + 1)}
    links = {f"rocker{i}": [f"O{i}", f"B{i}"] for i in range(n + 1)} | {f"coupler{i}": [f"B{i}", f"B{i + 1}"] for i in range(n)}
    # pull every even rocker a little to the side so no dyad is drawn stretched
    for i in range(1, n + 1):
        joints[f"B{i}"] = (i + 0.1 * (-1) ** i, 0.98)
    return Sketch(joints, links, ground=[f"O{i}" for i in range(n + 1)], driver="rocker0", name=f"four_bar_chain_{n}")


def mixed_chain(n: int, seed: int = 0) -> Sketch:
    """A crank then n groups in turn RRR, RRP, RPR, PRP, triad, each hung from the previous group's joint."""
    rng = np.random.default_rng(seed)
    joints = {"O": np.zeros(2), "A": np.array([0.3, 0.1])}
    links, ground, slides = {"crank": ["O", "A"]}, ["O"], []
    last = "A"
    for k in range(n):
        x0 = joints[last]
        g = f"G{k}"
        joints[g] = x0 + np.array([0.5, -0.6])
        ground.append(g)
        kind = ("RRR", "RRP", "RPR", "PRP", "triad")[k % 5]
        if kind == "RRR":
            joints[f"J{k}"] = x0 + np.array([0.4, 0.2]) + rng.uniform(-0.05, 0.05, 2)
            links |= {f"a{k}": [last, f"J{k}"], f"b{k}": [g, f"J{k}"]}
            last = f"J{k}"
        elif kind == "RRP":
            joints[f"J{k}"] = x0 + np.array([0.5, 0.1])
            links |= {f"a{k}": [last, f"J{k}"], f"s{k}": [f"J{k}"]}
            slides.append(Slide(f"s{k}", "ground", (1.0, 0.2)))
            last = f"J{k}"
        elif kind == "RPR":
            joints[f"R{k}"] = joints[g] + np.array([0.3, 0.8])
            links |= {f"blk{k}": [last], f"arm{k}": [g, f"R{k}"]}
            slides.append(Slide(f"blk{k}", f"arm{k}", tuple(x0 - joints[g])))
            last = f"R{k}"
        elif kind == "PRP":
            joints[f"J{k}"] = x0 + np.array([0.2, 0.3])
            links |= {f"p{k}": [f"J{k}"], f"q{k}": [f"J{k}", f"T{k}"]}
            joints[f"T{k}"] = joints[f"J{k}"] + np.array([0.1, 0.1])
            slides += [Slide(f"p{k}", prev_link(links, last), (1.0, 1.0)), Slide(f"q{k}", "ground", (1.0, -0.5))]
            last = f"T{k}"
        else:
            e2, e3 = f"H{k}", f"K{k}"
            joints[e2], joints[e3] = x0 + np.array([1.0, 0.5]), x0 + np.array([1.0, -0.5])
            ground += [e2, e3]
            p1, p2, p3 = f"P{k}a", f"P{k}b", f"P{k}c"
            joints[p1], joints[p2], joints[p3] = x0 + np.array([0.35, 0.05]), x0 + np.array([0.65, 0.25]), x0 + np.array([0.65, -0.2])
            links |= {f"T{k}": [p1, p2, p3], f"L{k}a": [last, p1], f"L{k}b": [e2, p2], f"L{k}c": [e3, p3]}
            last = p1
    return Sketch(joints, links, ground=ground, slides=slides, driver="crank", name=f"mixed_chain_{n}")


def prev_link(links, joint):
    return next(k for k, js in reversed(links.items()) if joint in js)


def best(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(max(repeats, 5)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


FIRST_SIMULATE = """
import sys, time
t0 = time.perf_counter()
import assurjax
t1 = time.perf_counter()
scene = assurjax.load_scene(sys.argv[1])
t2 = time.perf_counter()
sol = assurjax.simulate(scene, stop=None, t1=0.2)
t3 = time.perf_counter()
print(t2 - t1, t3 - t2)
"""


JANSEN = """
[scene]
name = "jansen"
gravity = [0.0, -9.81]

[sketch]
driver = "crank"
ground = ["O", "Z"]
joints = {{ {joints} }}

[sketch.links]
crank = {{ joints = ["O", "M"], density = 0.5 }}
upper = {{ joints = ["M", "B"], density = 0.5 }}
lower = {{ joints = ["M", "D"], density = 0.5 }}
triangle = {{ joints = ["Z", "B", "C"], density = 0.02 }}
rocker = {{ joints = ["Z", "D"], density = 0.5 }}
bar = {{ joints = ["C", "E"], density = 0.5 }}
foot = {{ joints = ["D", "E", "F"], density = 0.02 }}

[state]
omega0 = 2.0
"""


def jansen_joints() -> str:
    """The leg at crank angle 0.4 rad from the holy numbers (mm -> m), by circle intersections."""
    n = dict(a=38.0, b=41.5, c=39.3, d=40.1, e=55.8, f=39.4, g=36.7, h=65.7, i=49.0, j=50.0, k=61.9, l=7.8, m=15.0)

    def circles(p, r, q, s, pick):
        d = q - p
        L = np.hypot(*d)
        a = (r**2 - s**2 + L**2) / (2 * L)
        h = np.sqrt(r**2 - a**2)
        pair = (p + a * d / L + h * np.array([-d[1], d[0]]) / L, p + a * d / L - h * np.array([-d[1], d[0]]) / L)
        return min(pair, key=pick)

    low, left = (lambda x: x[1]), (lambda x: x[0])
    O, Z, M = np.zeros(2), np.array([-n["a"], -n["l"]]), n["m"] * np.array([np.cos(0.4), np.sin(0.4)])
    B = circles(M, n["j"], Z, n["b"], low)
    D = circles(M, n["k"], Z, n["c"], low)
    C = circles(B, n["d"], Z, n["e"], left)
    E = circles(C, n["f"], D, n["g"], left)
    F = circles(E, n["h"], D, n["i"], low)
    pts = dict(O=O, Z=Z, M=M, B=B, C=C, D=D, E=E, F=F)
    return ", ".join(f"{k} = [{float(v[0]) / 1000!r}, {float(v[1]) / 1000!r}]" for k, v in pts.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    out = {"machine": platform.machine(), "python": platform.python_version(), "note": "shared 2-core machine: timings are noisy"}

    for sk in (four_bar_chain(40), mixed_chain(40)):
        dec = decompose(sk)
        assert len(dec.groups) == 41, len(dec.groups)
        t_dec = best(lambda: decompose(sk), args.repeats)
        t_build = best(lambda: build(sk), args.repeats)
        out[sk.name] = {"groups": len(dec.groups) - 1, "links": len(sk.links), "decompose_ms": 1e3 * t_dec, "build_ms": 1e3 * t_build,
                        "kinds": sorted({g.kind for g in dec.groups})}
        print(f"{sk.name}: {len(dec.groups) - 1} groups, {len(sk.links)} links: decompose {1e3 * t_dec:.1f} ms, build {1e3 * t_build:.1f} ms")

    with tempfile.TemporaryDirectory() as tmp:
        sketch_path = Path(tmp) / "jansen_sketch.toml"
        sketch_path.write_text(JANSEN.format(joints=jansen_joints()))
        scene = assurjax.load_scene(sketch_path)
        explicit_path = Path(tmp) / "jansen_explicit.toml"
        explicit_path.write_text(explicit_toml(scene))
        again = assurjax.load_scene(explicit_path)
        import jax

        same = jax.tree.structure(scene.mechanism) == jax.tree.structure(again.mechanism)
        runs = {"sketch": [], "explicit": []}
        for _ in range(args.repeats):
            for label, path in (("sketch", sketch_path), ("explicit", explicit_path)):
                res = subprocess.run([sys.executable, "-c", FIRST_SIMULATE, str(path)], capture_output=True, text=True, check=True,
                                     env={**__import__("os").environ, "ASSURJAX_NO_CACHE": "1"})
                load_s, first_s = map(float, res.stdout.split())
                runs[label].append({"load_s": load_s, "first_simulate_s": first_s})
    first = {k: min(r["first_simulate_s"] for r in v) for k, v in runs.items()}
    load = {k: min(r["load_s"] for r in v) for k, v in runs.items()}
    out["jansen_compile"] = {"same_pytree_structure": same, "runs": runs, "best_first_simulate_s": first, "best_load_s": load,
                             "ratio_sketch_over_explicit": first["sketch"] / first["explicit"]}
    print(f"Jansen leg, same pytree structure as its explicit form: {same}")
    for k in runs:
        print(f"  {k:8s}: load {load[k] * 1e3:.1f} ms, first simulate (trace + compile + run) {first[k]:.2f} s (best of {args.repeats})")
    print(f"  ratio sketch / explicit: {first['sketch'] / first['explicit']:.3f}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "decomposition.json").write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {RESULTS / 'decomposition.json'}")


if __name__ == "__main__":
    main()
