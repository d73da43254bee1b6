"""Time spent compiling numba kernels, kept apart from the time step's timers.

The kernels are compiled lazily, at their first call (``@njit(cache=True)`` loads them from the
cache instead when it holds them), so on a cold cache the first steps of a run, and the first
collision much later, spend minutes in the compiler. :data:`CLOCK` listens to numba's
``numba:compile`` events (a real compilation, not a load from the cache) and adds up their wall
time, nested compilations once; ``Simulation.step`` takes what falls inside an effect out of that
effect's timer, ``run_scene`` records the run's total as ``compile_seconds`` and keeps it out of
MLUPS, and the progress bar says "compiling kernels" while it lasts (:meth:`CompileClock.watch`).
The clock reads only ``time.perf_counter``: it changes no number of a run.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Callable

from numba.core import event


class CompileClock(event.Listener):
    """Wall seconds spent inside numba compilations (outermost ones: a kernel that compiles the
    functions it calls counts once), and the callbacks told when one starts and ends."""

    def __init__(self):
        self.seconds = 0.0
        self.depth = 0
        self._t0 = 0.0
        self._watchers: list[Callable[[bool], None]] = []

    def on_start(self, ev) -> None:
        if self.depth == 0:
            self._t0 = time.perf_counter()
            self._tell(True)
        self.depth += 1

    def on_end(self, ev) -> None:
        self.depth = max(0, self.depth - 1)
        if self.depth == 0:
            self.seconds += time.perf_counter() - self._t0
            self._tell(False)

    def now(self) -> float:
        """Seconds compiled so far, a compilation under way included."""
        return self.seconds + (time.perf_counter() - self._t0 if self.depth else 0.0)

    def _tell(self, compiling: bool) -> None:
        for w in list(self._watchers):
            w(compiling)

    @contextmanager
    def watch(self, callback: Callable[[bool], None]):
        """Call ``callback(True)`` when a compilation starts and ``callback(False)`` when it ends,
        within the ``with`` block."""
        self._watchers.append(callback)
        try:
            yield self
        finally:
            self._watchers.remove(callback)


#: the process's compile clock (registered once, at import)
CLOCK = CompileClock()
event.register("numba:compile", CLOCK)
