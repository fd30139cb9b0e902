"""Frame budget: stamp each pipeline stage with a replaceable clock.

Usage (one `StageTimer` per frame; the clock is injected so tests can drive it):

    timer = StageTimer(clock)
    ... detect ...
    timer.stamp("detect")
    ... track ...
    timer.stamp("track")
    timer.stage_ms   # {"detect": 0.41, "track": 0.05}
    timer.total_ms   # from construction to the last stamp

`BudgetStats` keeps every frame's totals and per-stage times for the median / p99 summary
that `occloc run` and `occloc bench` print.

Threads: the budget is stated for one core (`DEFAULT_THREADS`). `threads(n)` / `one_core()` put
OpenCV on n threads inside a block; `limit_blas_threads(n)` caps numpy's BLAS pool, which only
works before numpy is first imported (the command line calls it first thing). Video decoding
threads are the frame source's (`receiver.io.sources.open_source(threads=)`).
"""

from __future__ import annotations

import math
import os
import sys
import time
from contextlib import contextmanager
from typing import Callable, Iterator

# numpy and OpenCV are imported where they are used: this module is loaded before either
# (limit_blas_threads must run before numpy's first import to take effect).

# Threads the frame budget is stated for: one core.
DEFAULT_THREADS = 1
# Environment variables that size the BLAS / OpenMP pools of numpy's (and SciPy's) BLAS when
# it loads: OpenBLAS, an OpenMP build, MKL.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

Clock = Callable[[], float]  # seconds, monotonic (time.perf_counter by default)


class StageTimer:
    """Milliseconds spent in each named stage of one frame. Stamping a name twice adds up."""

    def __init__(self, clock: Clock = time.perf_counter):
        self._clock = clock
        self._t0 = clock()
        self._last = self._t0
        self.stage_ms: dict[str, float] = {}

    def stamp(self, stage: str) -> float:
        """Close `stage` at the current clock reading; returns its milliseconds."""
        now = self._clock()
        ms = (now - self._last) * 1000.0
        self.stage_ms[stage] = self.stage_ms.get(stage, 0.0) + ms
        self._last = now
        return ms

    @property
    def total_ms(self) -> float:
        return (self._last - self._t0) * 1000.0


def percentile(values, q: float) -> float:
    """q-th percentile (0-100) of `values`, nan when empty or when one is nan: the number
    `np.percentile(values, q)` gives (its default "linear" method, its virtual index and its
    lerp arithmetic), computed on a sorted list. np.percentile calls np.unique, whose first call
    imports numpy.ma (~20 ms, the only use of it by a photo's `occloc run` summary)."""
    v = sorted(float(x) for x in values)
    n = len(v)
    if n == 0 or v[-1] != v[-1] or any(x != x for x in v):
        return float("nan")
    pos = (n - 1) * (q / 100.0)  # numpy's virtual index
    if pos >= n - 1:
        return v[-1]
    lo = max(math.floor(pos), 0)
    t = pos - lo
    a, b = v[lo], v[lo + 1]
    d = b - a
    return b - d * (1.0 - t) if t >= 0.5 else a + d * t


class BudgetStats:
    """Per-frame total and per-stage milliseconds over a run."""

    def __init__(self):
        self.total_ms: list[float] = []
        self.stage_ms: dict[str, list[float]] = {}

    def add(self, total_ms: float, stage_ms: dict[str, float]) -> None:
        self.total_ms.append(total_ms)
        for name, ms in stage_ms.items():
            self.stage_ms.setdefault(name, []).append(ms)

    def summary(self) -> dict:
        """{"frames", "total": {"median_ms", "p99_ms"}, "stages": {name: {...}}}."""
        def stat(v):
            return {"median_ms": percentile(v, 50), "p99_ms": percentile(v, 99)}
        return {"frames": len(self.total_ms), "total": stat(self.total_ms),
                "stages": {k: stat(v) for k, v in self.stage_ms.items()}}


def limit_blas_threads(n: int, environ=os.environ, modules=sys.modules) -> bool:
    """Size numpy's BLAS thread pool to n threads: sets `BLAS_THREAD_VARS` when numpy is not loaded
    yet (read once, when its BLAS library loads). Returns False, changing nothing, when numpy is
    already loaded (then the pool is what the environment said at that time)."""
    if "numpy" in modules:
        return False
    for name in BLAS_THREAD_VARS:
        environ[name] = str(int(n))
    return True


@contextmanager
def threads(n: int) -> Iterator[None]:
    """OpenCV on n threads inside the block (by default OpenCV splits some calls over every
    core), restored afterwards."""
    import cv2
    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def one_core():
    """OpenCV on one thread inside the block: the frame budget is stated for one core."""
    return threads(1)
