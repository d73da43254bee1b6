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


def measure_interleaved(contenders: list[Contender], reps: int, monitor: LoadMonitor | None = None,
                        max_rounds: int | None = None, quiet_cores: float = 0.15,
                        progress: Callable[[str], None] | None = None) -> list[dict]:
    """Rounds of one timed repetition of every contender, in an order rotated from round to round.

    Before each timed repetition one untimed unit brings the contender's data back into the
    caches (the other contenders evicted it), so every contender starts alike. With a
    ``monitor``, a round in which other processes (plus hypervisor steal) used more than
    ``quiet_cores`` is marked disturbed and rounds continue until ``reps`` quiet ones are in or
    ``max_rounds`` have run. The contenders' ``rates`` then hold the quiet rounds only if there
    are at least three of them, else all rounds. Returns one load reading per round, with
    ``quiet`` and ``used`` flags.
    """
    rounds: list[dict] = []
    m = len(contenders)
    max_rounds = max(reps, max_rounds or reps)
    per_round: dict[str, list[float]] = {c.key: [] for c in contenders}
    n_quiet = 0
    r = 0
    while r < max_rounds and n_quiet < reps:
        if monitor:
            monitor.start()
        order = [contenders[(i + r) % m] for i in range(m)]
        if r % 2:  # alternate direction too, so no contender always follows the same neighbour
            order.reverse()
        for c in order:
            _timed(c, 1)
            dt = _timed(c, c.n)
            per_round[c.key].append(c.work * c.n / dt)
        info = monitor.read() if monitor else {}
        other = (info.get("foreign_cores") or 0.0) + (info.get("steal_cores") or 0.0)
        info["quiet"] = info.get("foreign_cores") is None or other <= quiet_cores
        n_quiet += info["quiet"]
        rounds.append(info)
        r += 1
        if progress:
            state = "quiet" if info["quiet"] else f"DISTURBED (other jobs used {other:.2f} cores)"
            progress(f"round {r}: {state}; {n_quiet}/{reps} quiet rounds so far")
    use_quiet = n_quiet >= min(3, reps)
    for i, info in enumerate(rounds):
        info["used"] = bool(info["quiet"] or not use_quiet)
    for c in contenders:
        c.rates = [x for x, info in zip(per_round[c.key], rounds) if info["used"]]
        c.meta["rates_all_rounds"] = per_round[c.key]
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
