"""Timing shared by the benchmark scripts."""

from __future__ import annotations

import time

import jax


def best_time(fn, repeats: int = 7, budget: float = 3.0) -> float:
    """Best wall time (s) of up to ``repeats`` warm calls of ``fn`` (the first call, which
    compiles, is not counted), stopping early once ``budget`` seconds are spent."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
        if sum(times) > budget:
            break
    return min(times)
