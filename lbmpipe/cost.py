"""Run-time estimate of a scene: fluid node updates divided by the solver's throughput.

``DEFAULT_MLUPS`` (million lattice-node updates per second) is the whole fluid-only solver step
on ``REFERENCE_THREADS`` threads, calibrated from ``benchmarks/fluid.py`` (row "lbmpipe BGK +
bounce-back wall", the paper's pipe 50 x 50 x 100, float64; the calibration run is recorded in
benchmarks/README.md), rounded down. Scenes with a
body force and the flux sum, interpolated walls or particles do more work per step and run
slower. Throughput is assumed to scale linearly with the thread count, which over-estimates it
once memory bandwidth saturates: treat the estimate as a lower bound on wall time for many
threads.
"""

from __future__ import annotations

import os

import numpy as np

DEFAULT_MLUPS = 150.0
REFERENCE_THREADS = 2


def pipe_fluid_nodes(n_d: int, n_len: int) -> int:
    """Nodes of an ``n_d x n_d x n_len`` block whose centres, at ``(i + 1/2) dx``, lie strictly
    inside the circle of diameter ``n_d dx`` centred in the cross-section."""
    c = (np.arange(n_d) + 0.5) - n_d / 2.0
    inside = (c[:, None] ** 2 + c[None, :] ** 2) < (n_d / 2.0) ** 2
    return int(np.count_nonzero(inside)) * int(n_len)


def fluid_nodes(kind: str, shape: tuple[int, int, int]) -> int:
    """Fluid node count of a ``pipe`` (circle cross-section) or ``box`` (all nodes) domain."""
    if kind == "pipe":
        return pipe_fluid_nodes(shape[0], shape[2])
    return int(shape[0]) * int(shape[1]) * int(shape[2])


def throughput_mlups(threads: int | None = None, mlups: float | None = None) -> float:
    """Expected MLUPS on ``threads`` threads (None: all cores), from ``mlups`` at REFERENCE_THREADS."""
    cores = os.cpu_count() or 1
    t = cores if threads is None else max(1, min(int(threads), cores))
    return (DEFAULT_MLUPS if mlups is None else mlups) * t / REFERENCE_THREADS


def estimate_seconds(params, threads: int | None = None, mlups: float | None = None) -> float:
    """Wall-clock seconds for ``params.n_steps`` steps over ``params.fluid_nodes`` fluid nodes."""
    return params.fluid_nodes * params.n_steps / (throughput_mlups(threads, mlups) * 1e6)
