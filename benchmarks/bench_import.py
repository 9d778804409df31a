"""Import time of the package: what ``import assurjax`` adds to importing jax, equinox and diffrax.

Each measurement runs in a fresh interpreter (nothing cached in ``sys.modules``): first
``import jax, equinox, diffrax`` is timed, then ``import assurjax`` in the same process,
so the second number is what the package itself costs. The median of several fresh
processes is reported, with the heavy modules that ``import assurjax`` must not load
(matplotlib, optax, the command line, the plots) checked absent. Target: < 0.3 s added.

Also times ``import assurjax.viz`` and ``import assurjax.synthesis`` (loaded on first use).

Saves benchmarks/results/import.json. Run: python benchmarks/bench_import.py
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPEATS = 7
MUST_STAY_UNLOADED = ("matplotlib", "optax", "assurjax.cli", "assurjax.viz", "assurjax.synthesis", "tqdm")

PROBE = """
import json, sys, time
t = time.perf_counter(); import jax, equinox, diffrax; base = time.perf_counter() - t
t = time.perf_counter(); import assurjax; package = time.perf_counter() - t
loaded = [m for m in {unloaded!r} if m in sys.modules]
t = time.perf_counter(); import assurjax.viz; viz = time.perf_counter() - t
t = time.perf_counter(); import assurjax.synthesis; synthesis = time.perf_counter() - t
print(json.dumps(dict(base=base, package=package, viz=viz, synthesis=synthesis, loaded=loaded)))
"""


def one_process() -> dict:
    env = dict(os.environ, PYTHONPATH=str(HERE.parent) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", PROBE.format(unloaded=MUST_STAY_UNLOADED)], env=env,
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    runs = [one_process() for _ in range(REPEATS)]
    median = {k: statistics.median(r[k] for r in runs) for k in ("base", "package", "viz", "synthesis")}
    loaded = sorted({m for r in runs for m in r["loaded"]})
    import jax

    results = dict(
        machine=dict(platform=platform.platform(), cpus=os.cpu_count(), python=platform.python_version(), jax=jax.__version__,
                     note="shared machine: absolute times are noisy"),
        repeats=REPEATS,
        median_s=dict(jax_equinox_diffrax=median["base"], assurjax_added=median["package"],
                      viz_on_first_use=median["viz"], synthesis_on_first_use=median["synthesis"]),
        target_added_s=0.3,
        heavy_modules_loaded_by_import_assurjax=loaded,
        runs=runs,
    )
    out = HERE / "results" / "import.json"
    out.write_text(json.dumps(results, indent=1))
    print(f"import jax, equinox, diffrax: {median['base']:.3f} s; import assurjax adds {median['package']:.3f} s "
          f"(target < 0.3 s); heavy modules loaded: {loaded or 'none'}")
    print(f"on first use: assurjax.viz {median['viz']:.3f} s, assurjax.synthesis {median['synthesis']:.3f} s")
    print(f"saved {out}")


if __name__ == "__main__":
    main()
