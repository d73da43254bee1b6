"""Helpers shared by the benchmark scripts: interleaved median timing, thread control, machine
description, memory-bandwidth kernels and a monitor of CPU time used by other processes.

Why interleaving: the benchmark machine is shared. Load from other jobs drifts over seconds to
minutes; if contender A ran all its repetitions first and B afterwards, a drift would show up as a
difference between A and B. Running one repetition of every contender per round, rotating the
order each round, spreads any drift over all of them alike, so ratios within one run stay
meaningful even when absolute figures wobble.
"""

from __future__ import annotations

import os
import platform
import resource
import statistics
import time
from dataclasses import dataclass, field
from typing import Callable

import numba
import numpy as np
from numba import njit, prange

# --------------------------------------------------------------------------------------------
# threads


def available_threads() -> int:
    return int(numba.config.NUMBA_NUM_THREADS)


def set_threads(n: int) -> None:
    """Thread count of numba's parallel regions (pystencils kernels carry theirs in the code)."""
    numba.set_num_threads(int(n))


# --------------------------------------------------------------------------------------------
# machine


def _read(path: str) -> str | None:
    try:
        with open(path) as fh:
            return fh.read().strip()
    except OSError:
        return None


def _cache_bytes(level: int) -> int | None:
    """Size of the cache of ``level`` seen by cpu0 (sysfs), in bytes."""
    base = "/sys/devices/system/cpu/cpu0/cache"
    try:
        entries = sorted(os.listdir(base))
    except OSError:
        return None
    for e in entries:
        if _read(f"{base}/{e}/level") == str(level) and _read(f"{base}/{e}/type") in ("Unified", "Data"):
            s = _read(f"{base}/{e}/size") or ""
            mult = {"K": 1024, "M": 1024**2, "G": 1024**3}.get(s[-1:], 1)
            try:
                return int(s.rstrip("KMG")) * mult
            except ValueError:
                return None
    return None


def last_level_cache_bytes() -> int | None:
    for level in (4, 3, 2):
        b = _cache_bytes(level)
        if b:
            return b
    return None


def machine_info() -> dict:
    """CPU model (py-cpuinfo when installed, else /proc/cpuinfo), cores, caches, numba's view."""
    model = None
    flags: list[str] = []
    try:
        import cpuinfo  # optional: the package's `bench` extra

        info = cpuinfo.get_cpu_info()
        model = info.get("brand_raw")
        flags = info.get("flags", [])
        source = "py-cpuinfo"
    except Exception:  # not installed, or it failed on this platform
        source = "/proc/cpuinfo"
        text = _read("/proc/cpuinfo") or ""
        for line in text.splitlines():
            if line.startswith("model name") and model is None:
                model = line.split(":", 1)[1].strip()
            if line.startswith("flags") and not flags:
                flags = line.split(":", 1)[1].split()
    simd = [f for f in ("avx512f", "avx2", "fma", "sse4_2", "neon", "sve") if f in flags]
    try:
        import llvmlite.binding as ll

        llvm_cpu = ll.get_host_cpu_name()
    except Exception:
        llvm_cpu = None
    return {
        "cpu_model": model or platform.processor() or "unknown",
        "cpu_model_source": source,
        "cores_logical": os.cpu_count(),
        "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "simd": simd,
        "l2_bytes": _cache_bytes(2),
        "llc_bytes": last_level_cache_bytes(),
        "llvm_cpu_name": llvm_cpu,  # the target numba compiles for (decides its vector width)
        "numba": numba.__version__,
        "numba_threading_layer": _threading_layer(),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def _threading_layer() -> str | None:
    try:
        return numba.threading_layer()
    except ValueError:  # no parallel region has run yet
        return None


# --------------------------------------------------------------------------------------------
# load from other processes


def _proc_stat_cpu() -> tuple[float, float] | None:
    """(busy seconds, steal seconds) summed over all CPUs since boot, from /proc/stat."""
    text = _read("/proc/stat")
    if not text:
        return None
    parts = text.splitlines()[0].split()[1:]
    v = [int(x) for x in parts] + [0] * 10
    user, nice, system, idle, iowait, irq, softirq, steal = v[:8]
    hz = os.sysconf("SC_CLK_TCK")
    busy = user + nice + system + irq + softirq  # guest time is already inside user
    return busy / hz, steal / hz


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


class LoadMonitor:
    """CPU used by *other* processes while we measure, in cores (0 = machine was ours alone).

    ``foreign = (busy CPU time of the whole machine - CPU time of this process) / wall time``,
    from /proc/stat (jiffy resolution, so only meaningful over windows of a second or more), plus
    the hypervisor's steal time, which counts CPU that a virtual machine wanted but did not get.
    """

    def __init__(self):
        self.ok = _proc_stat_cpu() is not None
        self.start()

    def start(self) -> None:
        self._t = time.perf_counter()
        self._s = _self_cpu()
        self._p = _proc_stat_cpu()

    def read(self) -> dict:
        wall = time.perf_counter() - self._t
        me = _self_cpu() - self._s
        p = _proc_stat_cpu()
        if not self.ok or p is None or wall <= 0:
            return {"wall_s": wall, "foreign_cores": None, "steal_cores": None, "own_cores": me / max(wall, 1e-9)}
        busy = p[0] - self._p[0]
        steal = p[1] - self._p[1]
        return {
            "wall_s": wall,
            "foreign_cores": max(0.0, (busy - me) / wall),
            "steal_cores": steal / wall,
            "own_cores": me / wall,
        }


# --------------------------------------------------------------------------------------------
# interleaved timing


@dataclass
class Contender:
    """One thing to time. ``run(n)`` performs ``n`` units of work (steps, copies) and returns
    nothing; ``work`` is the amount one unit counts for (lattice nodes, bytes moved)."""

    key: str
    run: Callable[[int], None]
    work: float
    threads: int = 1
    meta: dict = field(default_factory=dict)
    n: int = 1  # units per repetition, set by calibrate()
    rates: list[float] = field(default_factory=list)  # work per second, one per repetition

    @property
    def median(self) -> float:
        return statistics.median(self.rates) if self.rates else float("nan")

    @property
    def spread(self) -> float:
        """(max - min) / median of the repetitions: how steady the figure was."""
        if len(self.rates) < 2:
            return 0.0
        return (max(self.rates) - min(self.rates)) / self.median


def _timed(c: Contender, n: int) -> float:
    set_threads(c.threads)
    t0 = time.perf_counter()
    c.run(n)
    return time.perf_counter() - t0


def calibrate(contenders: list[Contender], rep_seconds: float, warmup: int = 1, min_units: int = 2) -> None:
    """Warm up (compile, fault in pages, fill caches) and pick units per repetition so that one
    repetition lasts about ``rep_seconds``."""
    for c in contenders:
        for _ in range(warmup):
            _timed(c, 1)
        dt = _timed(c, 1)
        if dt < rep_seconds / 20:  # too short to extrapolate from one unit: time a handful
            k = max(2, int(rep_seconds / 20 / max(dt, 1e-7)))
            dt = _timed(c, k) / k
        c.n = max(min_units, int(round(rep_seconds / max(dt, 1e-9))))


def _other_cores(info: dict) -> float | None:
    fc = info.get("foreign_cores")
    return None if fc is None else fc + (info.get("steal_cores") or 0.0)


def wait_until_quiet(monitor: LoadMonitor, allowed_cores: float, max_wait: float, window: float = 0.25) -> float | None:
    """Sleep in short windows until other processes use at most ``allowed_cores`` (or ``max_wait``
    seconds pass); returns the last reading. Cheaper than timing a repetition that would be
    thrown away."""
    t_end = time.perf_counter() + max_wait
    other = None
    while time.perf_counter() < t_end:
        monitor.start()
        time.sleep(window)
        other = _other_cores(monitor.read())
        if other is None or other <= allowed_cores:
            break
    return other


QUIET, SHARED, DISTURBED = "quiet", "shared", "disturbed"


def measure_interleaved(contenders: list[Contender], reps: int, monitor: LoadMonitor | None = None,
                        max_rounds: int | None = None, quiet_cores: float = 0.15, cores: int | None = None,
                        time_limit: float | None = None, progress: Callable[[str], None] | None = None) -> list[dict]:
    """Rounds of one timed repetition of each contender, in an order rotated from round to round.

    Before each timed repetition one untimed unit brings the contender's data back into the
    caches (the other contenders evicted it), so every contender starts alike.

    With a ``monitor`` each timed repetition is classified by the CPU that other processes used
    meanwhile: ``quiet`` (at most ``quiet_cores``), ``shared`` (more, but no more than the cores
    this contender leaves idle: a 1-thread run on 2 cores kept its core, only caches and memory
    were shared) or ``disturbed`` (others took CPU time from our threads; the figure is
    meaningless). A contender takes part in further rounds until it has ``reps`` usable (quiet or
    shared) repetitions, or ``max_rounds`` rounds or ``time_limit`` seconds have passed. When the
    last reading says the machine is busy, a contender that needs the cores waits (briefly) for
    them instead of timing a repetition that would be thrown away.

    A contender's ``rates`` are then its quiet repetitions if there are at least three, else its
    usable ones if at least three, else all; ``meta["status"]`` says which (quiet / shared /
    disturbed). Returns one summary per round.
    """
    max_rounds = max(reps, max_rounds or reps)
    cores = cores or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)
    hz = os.sysconf("SC_CLK_TCK")
    samples: dict[str, list[tuple[float, float | None, str]]] = {c.key: [] for c in contenders}
    rounds: list[dict] = []
    t0 = time.perf_counter()
    last_other = 0.0

    def usable(c):
        return sum(lv != DISTURBED for _, _, lv in samples[c.key])

    r = 0
    while r < max_rounds and (time_limit is None or time.perf_counter() - t0 < time_limit):
        need = [c for c in contenders if usable(c) < reps]
        if not need:
            break
        m = len(need)
        order = [need[(i + r) % m] for i in range(m)]
        if r % 2:  # alternate direction too, so no contender always follows the same neighbour
            order.reverse()
        count = {QUIET: 0, SHARED: 0, DISTURBED: 0}
        waited = 0.0
        for c in order:
            allowed = max(0, cores - c.threads) + quiet_cores
            if monitor and last_other is not None and last_other > allowed:
                tw = time.perf_counter()
                last_other = wait_until_quiet(monitor, allowed, max_wait=10.0)
                waited += time.perf_counter() - tw
            _timed(c, 1)
            if monitor:
                monitor.start()
            dt = _timed(c, c.n)
            other = _other_cores(monitor.read()) if monitor else None
            slack = 2.0 / hz / dt  # /proc/stat counts whole clock ticks: short repetitions are coarse
            if other is None or other <= quiet_cores + slack:
                level = QUIET
            elif other <= allowed + slack:
                level = SHARED
            else:
                level = DISTURBED
            count[level] += 1
            last_other = other
            samples[c.key].append((c.work * c.n / dt, other, level))
        r += 1
        rounds.append({"timed": m, **count, "waited_s": waited})
        if progress:
            left = sum(usable(c) < reps for c in contenders)
            progress(f"round {r}: {m} timed ({count[QUIET]} quiet, {count[SHARED]} shared, "
                     f"{count[DISTURBED]} disturbed; waited {waited:.0f} s for idle cores); "
                     f"{left} contenders still short of {reps} usable repetitions")
    for c in contenders:
        s = samples[c.key]
        quiet = [x for x, _, lv in s if lv == QUIET]
        ok = [x for x, _, lv in s if lv != DISTURBED]
        if len(quiet) >= min(3, reps):
            c.rates, c.meta["status"] = quiet, QUIET
        elif len(ok) >= min(3, reps):
            c.rates, c.meta["status"] = ok, SHARED
        else:
            c.rates, c.meta["status"] = [x for x, _, _ in s], DISTURBED
        c.meta["reps_total"] = len(s)
        c.meta["samples"] = [{"rate": x, "other_cores": o, "level": lv} for x, o, lv in s]
    return rounds


# --------------------------------------------------------------------------------------------
# memory bandwidth


@njit(parallel=True, cache=True, fastmath=False)
def copy_plain(src, dst, one):
    """dst = src with ordinary vector loads and stores (as an LBM sweep does).

    The multiplication by a run-time 1.0 keeps LLVM from turning the loop into a call to
    ``memcpy``, whose large-copy path (``rep movsb``, streaming stores) skips the read-for-ownership
    of the destination that the LBM kernels pay; without fastmath it cannot be folded away.
    """
    for i in prange(src.size):
        dst[i] = src[i] * one


@njit(parallel=True, cache=True)
def copy_memcpy(src, dst):
    """dst = src as written; LLVM lowers each thread's chunk to ``memcpy``."""
    for i in prange(src.size):
        dst[i] = src[i]


def fmt_bytes(b: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if abs(b) < 1024 or unit == "GiB":
            return f"{b:.0f} {unit}" if unit == "B" else f"{b:.1f} {unit}"
        b /= 1024
    return f"{b:.1f} GiB"


# --------------------------------------------------------------------------------------------
# the fluid sweep alone, as the yardstick of the "floor" scripts


@dataclass
class SweepOnly:
    """The stream + collide kernel of a built ``Simulation``, on copies of its populations so that
    timing it changes nothing in the run: ``sweep_cols(a, b)`` sweeps columns ``a:b``; ``bounds``
    are the simulation's own column chunks, and ``run()`` sweeps them all, one after another (one
    core: each call is one chunk). ``src``/``dst`` are the (q, plane) buffers it reads and writes."""

    sim: object
    src: np.ndarray = field(init=False)
    dst: np.ndarray = field(init=False)
    bounds: list = field(init=False)

    def __post_init__(self):
        from lbmpipe.fluid import boundaries as bnd
        from lbmpipe.fluid.effects import StreamCollide

        self._sweep = next(e for e in self.sim.effects if isinstance(e, StreamCollide))
        self.src = bnd.plane_buffer(self.sim.f).copy()
        self.dst = bnd.plane_buffer(self.sim.f_next).copy()
        g = self.sim.grid
        ncol, nch = len(g.cols_x), self.sim.n_chunks
        self.bounds = [(k * ncol // nch, (k + 1) * ncol // nch) for k in range(nch)]
        self._tally = np.zeros(2)

    def sweep_cols(self, a: int, b: int) -> None:
        s, g = self.sim, self.sim.grid
        fx, fy, fz = s.force
        self._sweep.kernel(self.src, self.dst, g.shape[1], g.alloc_z, g.cols_x[a:b], g.cols_y[a:b], g.xm, g.xp, g.ym,
                           g.yp, g.z0, g.z1, g.nzw, s.omega, s.omega_minus, fx, fy, fz, 1, self._sweep.rho_min,
                           self._tally)

    def run(self) -> None:
        for a, b in self.bounds:
            self.sweep_cols(a, b)
