"""Helpers shared by the benchmark scripts: machine description, timing, JSON output."""

from __future__ import annotations

import json
import os
import platform
import resource
import time

import jax
import numpy as np


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict:
    """What the figures were measured on (CPU model, cores, load, versions)."""
    try:
        load = os.getloadavg()
    except OSError:
        load = None
    return dict(
        cpu=cpu_model(),
        cpus=os.cpu_count(),
        loadavg=load,
        platform=platform.platform(),
        jax=jax.__version__,
        device=str(jax.devices()[0]),
    )


def best_time(fn, *args, repeats: int = 3, budget_s: float = 5.0) -> float:
    """Minimum wall time of ``fn(*args)`` (blocked) over ``repeats`` calls.

    The minimum, not the mean: on a shared machine other processes only ever add
    time, so the minimum is the best estimate of the code's own cost. Stops early
    once ``budget_s`` is spent (a single slow run is then the figure).
    """
    best, spent = np.inf, 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        dt = time.perf_counter() - t0
        best, spent = min(best, dt), spent + dt
        if spent > budget_s:
            break
    return best


def compile_timed(jitted, *args):
    """``(compiled, seconds)``: ahead-of-time compile of a jitted function."""
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    return compiled, time.perf_counter() - t0


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def write_json(path: str, payload: dict) -> None:
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "w") as f:
        json.dump(payload, f, indent=1, default=float)
