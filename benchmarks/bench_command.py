"""``assurjax run SCENE``: the command's wall time, and its peak search's share.

Each run is a fresh process (import, scene, simulation, reactions, peak search, figures, CSV;
no animation: its cost does not depend on the code measured here), with JAX's on-disk
compilation cache in a new empty directory (cold: every program traced and compiled) and
then again with that directory filled (warm: the command's usual case from its second run;
tracing is still paid). The peak search (``cli._peaks``) is timed inside the process.

``--before REF`` also measures the package at git revision REF, run for run interleaved
with the working tree's, and reports the ratios.

    python benchmarks/bench_command.py [--before REF] [--repeats 2]   # writes results/command.json
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
SCENES = ("watt_sixbar", "press_with_friction", "triad_mechanism")  # three of the four bundled scenes with reactions outputs

CHILD = r"""
import json, sys, time
from assurjax import cli

spent = []
peaks = cli._peaks

def timed(*args, **kwargs):
    start = time.perf_counter()
    try:
        return peaks(*args, **kwargs)
    finally:
        spent.append(time.perf_counter() - start)

cli._peaks = timed
code = cli.main(["run", sys.argv[1], "--out", sys.argv[2], "--quiet", "--no-animation"])
print(json.dumps(dict(code=code, peaks_s=sum(spent))))
"""


def _run(code_dir: str, scene: str, cache: str) -> dict:
    """One command in a fresh process importing the package from ``code_dir``."""
    env = dict(os.environ, PYTHONPATH=code_dir, ASSURJAX_CACHE_DIR=cache, MPLBACKEND="Agg")
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-c", CHILD, scene, out], env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"assurjax run {scene} failed:\n{done.stderr[-3000:]}")
    return dict(wall_s=wall, **json.loads(done.stdout.strip().splitlines()[-1]))


def measure(code_dirs: dict, repeats: int) -> dict:
    """scene -> version -> cold and warm runs (each repeat with its own new cache)."""
    out = {}
    for scene in SCENES:
        out[scene] = {version: dict(cold=[], warm=[]) for version in code_dirs}
        for _ in range(repeats):
            for version, code_dir in code_dirs.items():
                with tempfile.TemporaryDirectory() as cache:
                    for kind in ("cold", "warm"):
                        out[scene][version][kind].append(_run(code_dir, scene, cache))
        for version in code_dirs:
            for kind in ("cold", "warm"):
                runs = out[scene][version][kind]
                print(f"{scene:20s} {version:7s} {kind}: wall {min(r['wall_s'] for r in runs):6.2f} s, "
                      f"peak search {min(r['peaks_s'] for r in runs):6.2f} s")
    return out


def ratios(runs: dict) -> dict:
    best = lambda scene, version, kind, key: min(r[key] for r in runs[scene][version][kind])  # noqa: E731
    return {scene: {f"{kind}_{key}": best(scene, "before", kind, key) / best(scene, "after", kind, key)
                    for kind in ("cold", "warm") for key in ("wall_s", "peaks_s")} for scene in SCENES}


def main():
    from bench_overhead import versions_main

    versions_main(__doc__, HERE / "results" / "command.json", measure, ratios)


if __name__ == "__main__":
    main()
