"""Jeffery orbit of a free circular cylinder in simple shear (issue 44, validation item 4); shared
by ``tests/test_jeffery.py`` (small) and ``benchmarks/jeffery.py`` (full size). Lattice units.

Setup (``sheared_cylinder``): plane Couette flow ``u_x = gamma (y - H/2)`` between two walls at
``y = 0`` and ``y = H`` moving at ``-U`` and ``+U`` (``gamma = 2U/H``; Ladd's moving half-way
bounce-back, exact for the linear profile at any tau), periodic in x (flow) and z (vorticity), the
fluid started on that profile. A free, neutrally buoyant cylinder (density 1: its inertia is the
fluid's, as in the paper) of diameter ``D`` and length ``L = 2D`` sits at the centre, its axis in
the flow-gradient plane (x-y) at angle ``phi0`` from the gradient (y) axis. It feels no force on
average (the centre plane moves at zero velocity) and tumbles about z.

Jeffery (1922): the axis of a spheroid of aspect ratio ``r`` in the shear plane turns at
``dphi/dt = gamma (r^2 cos^2 phi + sin^2 phi) / (r^2 + 1)`` (``phi`` from the gradient axis, in the
sense of the flow's rotation), so ``tan phi = r tan(2 pi t / T)`` with period
``T = (2 pi / gamma)(r + 1/r)``. A circular cylinder follows the same orbits with an equivalent
aspect ratio ``r_e`` (Bretherton 1962: any body of revolution does). For ``L/D = 2``:

* ``r_e = 1.914`` from the fit of Zhang, Smith, Jack & Montgomery-Smith (2011, J. Manuf. Sci. Eng.
  133, 051002) to their finite-element Stokes computations of cylinders,
  ``r_e = 0.000035 r^3 - 0.00467 r^2 + 0.764 r + 0.404`` (as coded in the ``fiberoripy`` package,
  ``aspect_ratios.get_zhang_aspect_ratio``); Jeffery's period ``T gamma = 15.31``. This is the
  reference (``R_E_ZHANG``).
* For context only: Cox's (1971) slender-body ``1.24 r / sqrt(ln r)`` gives 2.98 (not valid at
  ``r = 2``) and the experimental fit for long fibres ``0.742 r - 0.0017 r^2`` (Forgacs & Mason
  1959) gives 1.48. Published rules disagree at ``L/D = 2``, and the residual of Zhang's fit there is
  not known to us: the reference is uncertain by a few per cent.

Measured (``benchmarks/README.md``, "Issue 44: Jeffery orbit"; D = 8, Re_p = 0.1): the accurate
method's period is +4.0 % / +4.1 % above Jeffery's at tau 1 / 1.78 in a box of 6 diameters, +2.7 %
in one of 12 (about +2.5 % unbounded); the paper's +3.6 % / +6.0 %.

Measured (``period``): ``phi(t)`` from the body quaternion every ``every`` steps, unwrapped. After
a start-up of ``skip`` steps (the disturbance flow around the particle develops over a few
``D^2 / nu``), the time the axis takes to turn by pi from ``phi(skip)`` is exactly ``T / 2`` in
Jeffery's solution, whatever the starting angle: ``T = 2 (t(phi_a + pi) - t_a)``, linearly
interpolated between samples. ``fit_jeffery`` also fits ``(T, r, t0)`` of Jeffery's ``phi(t)`` to
the same samples (the fitted ``r`` is the cylinder's equivalent ratio as the solver sees it).
"""

from __future__ import annotations

import math
import time

import numpy as np

from ..fluid import boundaries as bnd
from ..fluid import effects as fx
from ..fluid.collision import MAGIC_EXACT_WALL, trt_omega_minus
from ..fluid.lattice import get_lattice
from ..particles import coupling as cp
from ..particles import shapes
from ..particles.rigid import Bodies, quat_from_axis_angle, rotate
from ..solver import Simulation

#: Zhang, Smith, Jack & Montgomery-Smith (2011): equivalent aspect ratio of a circular cylinder
R_E_ZHANG_FIT = (0.000035, -0.00467, 0.764, 0.404)


def r_e_zhang(r: float) -> float:
    """Equivalent ellipsoidal aspect ratio of a circular cylinder of aspect ratio ``r = L/D``
    (Zhang et al. 2011 fit; module docstring)."""
    a3, a2, a1, a0 = R_E_ZHANG_FIT
    return a3 * r**3 + a2 * r**2 + a1 * r + a0


R_E_ZHANG = r_e_zhang(2.0)  # 1.914 for L/D = 2


def jeffery_period(r_e: float, gamma: float = 1.0) -> float:
    """Jeffery's tumbling period ``(2 pi / gamma)(r_e + 1/r_e)``."""
    return 2.0 * math.pi / gamma * (r_e + 1.0 / r_e)


def jeffery_rate(phi, r_e: float, gamma: float = 1.0):
    """Jeffery's ``dphi/dt = gamma (r^2 cos^2 phi + sin^2 phi) / (r^2 + 1)``, ``phi`` from the
    gradient axis."""
    return gamma * (r_e**2 * np.cos(phi) ** 2 + np.sin(phi) ** 2) / (r_e**2 + 1.0)


def jeffery_phi(t, period: float, r_e: float, t0: float = 0.0):
    """Jeffery's angle from the gradient axis, continuous in ``t``: ``tan phi = r tan psi`` with
    ``psi = 2 pi (t - t0) / T``, on the branch where ``phi`` and ``psi`` pass each multiple of
    ``pi/2`` together."""
    psi = 2.0 * np.pi * (np.asarray(t, dtype=np.float64) - t0) / period
    k = np.floor(psi / np.pi + 0.5)  # psi - k pi in [-pi/2, pi/2): tan is monotonic there
    return np.arctan(r_e * np.tan(psi - k * np.pi)) + k * np.pi


def axis_angle(q) -> float:
    """Angle of the cylinder axis (body z) from the lab y axis towards +x."""
    p = rotate(np.asarray(q, dtype=np.float64), np.array([0.0, 0.0, 1.0]))
    return math.atan2(p[0], p[1])


def orientation(phi0: float) -> np.ndarray:
    """Quaternion that turns body z to ``(sin phi0, cos phi0, 0)``: a right angle about
    ``z x p``."""
    p = np.array([math.sin(phi0), math.cos(phi0), 0.0])
    return quat_from_axis_angle(np.cross([0.0, 0.0, 1.0], p), 0.5 * math.pi)


#: contender -> (particle_boundary, momentum_exchange, collision)
METHODS = {"paper": ("bounce_back", "ladd", "bgk"), "accurate": ("cli", "galilean", "trt")}


def sheared_cylinder(D: float, box, *, tau: float, re_p: float = 0.1, phi0: float = 0.5 * math.pi,
                     method: str = "paper", magic: float = MAGIC_EXACT_WALL, density: float = 1.0,
                     every: int = 10, skip: int | None = None, turn: float = math.pi, max_steps: int = 400000,
                     offset=(0.0, 0.0, 0.0)) -> dict:
    """Run the sheared cylinder (module docstring) until its axis has turned by ``turn`` after the
    start-up (``skip`` steps; default ``3 D^2 / nu``), or ``max_steps``. ``box`` = (Lx, H, Lz)
    nodes (flow, gradient between the walls, vorticity); the shear rate gives the particle Reynolds
    number ``re_p = gamma D^2 / nu``. ``method``: ``paper`` (half-way bounce-back, Ladd's exchange,
    BGK) or ``accurate`` (``cli``, ``galilean``, TRT with ``magic``).

    Returns the samples ``t``, ``phi`` (unwrapped), ``omega`` (lab z, sign flipped: the tumbling
    rate) and the particle centre's drift, with ``gamma``, ``nu``, ``skip`` and the wall time."""
    boundary, exchange, collision = METHODS[method]
    lx, h, lz = (int(b) for b in box)
    nu = (tau - 0.5) / 3.0
    gamma = re_p * nu / D**2
    u_wall = 0.5 * gamma * h
    skip = int(round(3.0 * D**2 / nu)) if skip is None else int(skip)
    grid = bnd.box_grid(get_lattice("D3Q15"), (lx, h, lz), (False, True, False))
    walls = fx.wall_effects(grid, "bounce_back", {"y-": (-u_wall, 0.0, 0.0), "y+": (u_wall, 0.0, 0.0)})
    centre = np.array([lx / 2.0, h / 2.0, lz / 2.0]) + np.asarray(offset, dtype=np.float64)
    bodies = Bodies.make(shapes.CYLINDER, [D / 2.0, D / 2.0, D], density, [centre], q=orientation(phi0)[None])
    system = cp.ParticleSystem(grid, bodies)
    pre, before, after = cp.particle_effects(system, wall_links=[w.links for w in walls], boundary=boundary,
                                             exchange=exchange)
    om_minus = trt_omega_minus(tau, magic) if collision == "trt" else None
    sim = Simulation.build(grid, collision=collision, omega=1.0 / tau, omega_minus=om_minus,
                           extra_effects=walls + pre + before + after)
    _, y, _ = grid.positions()
    sim.set_equilibrium(1.0, (gamma * (y[None, :, None] - h / 2.0), 0.0, 0.0))

    t_wall = time.perf_counter()
    ts, phis, oms = [0], [axis_angle(bodies.q[0])], [0.0]
    target = None
    steps = 0
    while steps < max_steps:
        sim.step(every)
        steps += every
        ts.append(steps)
        phis.append(phis[-1] + _wrap(axis_angle(bodies.q[0]) - phis[-1]))
        oms.append(-float(system.omega_lab()[0, 2]))
        if target is None and steps >= skip:
            target = phis[-1] + turn
        if target is not None and phis[-1] >= target:
            break
        if not np.isfinite(phis[-1]):
            raise FloatingPointError(f"the run diverged at step {steps}")
    return {"t": np.array(ts, dtype=np.float64), "phi": np.array(phis), "omega": np.array(oms), "gamma": gamma,
            "nu": nu, "skip": skip, "steps": steps, "box": (lx, h, lz), "D": D, "re_p": re_p, "tau": tau,
            "method": method, "drift": bodies.x[0] - centre, "seconds": time.perf_counter() - t_wall}


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def crossing(t, phi, value: float) -> float:
    """First time ``phi`` (increasing) reaches ``value``, linearly interpolated."""
    j = int(np.argmax(phi >= value))
    if phi[j] < value:
        raise ValueError(f"phi never reaches {value:.4f} (last {phi[-1]:.4f}): run longer")
    if j == 0:
        return float(t[0])
    return float(t[j - 1] + (value - phi[j - 1]) / (phi[j] - phi[j - 1]) * (t[j] - t[j - 1]))


def rate_at(run: dict, value: float) -> float:
    """Tumbling rate ``-Omega_z`` when ``phi`` first reaches ``value`` after the start-up, linearly
    interpolated between samples."""
    t, phi, om = run["t"], run["phi"], run["omega"]
    keep = t >= run["skip"]
    tc = crossing(t[keep], phi[keep], value)
    return float(np.interp(tc, t, om))


def period(run: dict) -> float:
    """Jeffery period measured as twice the time of a half turn after the start-up (module
    docstring), in steps."""
    t, phi = run["t"], run["phi"]
    ja = int(np.searchsorted(t, run["skip"]))
    return 2.0 * (crossing(t, phi, phi[ja] + math.pi) - t[ja])


def fit_jeffery(run: dict, r_guess: float = R_E_ZHANG) -> dict:
    """Least-squares fit of Jeffery's ``phi(t)`` (``T``, ``r``, ``t0``) to the samples after the
    start-up; returns ``period`` (steps), ``r_e`` and the rms residual (rad)."""
    from scipy.optimize import least_squares

    t, phi = run["t"], run["phi"]
    keep = t >= run["skip"]
    t, phi = t[keep], phi[keep]
    T0 = jeffery_period(r_guess, run["gamma"])
    # t0 of the guess: the time Jeffery's orbit takes from phi = 0 to the first sample's angle
    k = np.floor(phi[0] / np.pi + 0.5)
    t00 = t[0] - T0 / (2 * np.pi) * (np.arctan(np.tan(phi[0] - k * np.pi) / r_guess) + k * np.pi)

    def res(p):
        return jeffery_phi(t, p[0], p[1], p[2]) - phi

    sol = least_squares(res, [T0, r_guess, t00], x_scale=[T0, 1.0, T0])
    return {"period": float(sol.x[0]), "r_e": float(sol.x[1]), "t0": float(sol.x[2]),
            "rms": float(np.sqrt(np.mean(sol.fun**2)))}
