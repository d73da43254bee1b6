"""Physical <-> lattice unit conversion, and the lattice parameters derived from a scene.

The solver works in lattice units: ``dx = dt = 1`` and a reference density of 1 (the fluid's
``density_kg_m3``). Every physical quantity with dimension ``L^a T^b M^c`` therefore converts as
``q_lu = q_phys / (dx^a dt^b (rho dx^3)^c)``; each method below is that rule for one quantity,
and the ``*_phys`` method is its inverse. Physical units appear only here and at the I/O edges.

``derive(scene)`` turns a validated :class:`lbmpipe.scene.Scene` into :class:`LatticeParams`:
the relaxation time from ``nu = c_s^2 (tau - 1/2)`` (paper, after Eq. (6), with ``c = dx/dt = 1``),
the expected velocities (Poiseuille, plane Poiseuille, Couette) and the Mach number they imply,
and the step counts. Anything that makes the lattice run meaningless (``tau <= 1/2``, a Mach
number above ``numerics.mach_limit``) raises :class:`lbmpipe.scene.SceneError` naming the field
and a numerical fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from lbmpipe import cost
from lbmpipe.errors import SceneError
from lbmpipe.fluid.collision import MAGIC_EXACT_WALL, CollisionOperator, Relaxation, trt_omega_minus  # noqa: F401
from lbmpipe.fluid.lattice import CS2
from lbmpipe.particles.shapes import scene_shape, volume

CS = math.sqrt(CS2)
#: BGK is (linearly) stable only for tau > 1/2, and in practice marginal just above it.
TAU_MARGINAL = 0.55
#: Default of numerics.mach_limit: beyond it the O(Ma^2) compressibility error is no longer small.
DEFAULT_MACH_LIMIT = 0.35


@dataclass(frozen=True)
class Units:
    """Conversion between SI units and lattice units for spacing ``dx_m``, step ``dt_s`` and
    reference density ``rho_kg_m3`` (lattice density 1 == ``rho_kg_m3``)."""

    dx_m: float
    dt_s: float
    rho_kg_m3: float = 1000.0

    def __post_init__(self) -> None:
        for name in ("dx_m", "dt_s", "rho_kg_m3"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"Units.{name} must be a positive finite number, got {value!r}")

    # Scale of each dimension: L -> dx, T -> dt, M -> rho dx^3.
    @property
    def mass_scale(self) -> float:
        return self.rho_kg_m3 * self.dx_m**3

    def length(self, m: float) -> float:
        return m / self.dx_m

    def length_phys(self, lu: float) -> float:
        return lu * self.dx_m

    def time(self, s: float) -> float:
        """Physical time in (fractional) time steps."""
        return s / self.dt_s

    def time_phys(self, steps: float) -> float:
        return steps * self.dt_s

    def velocity(self, m_s: float) -> float:
        return m_s * self.dt_s / self.dx_m

    def velocity_phys(self, lu: float) -> float:
        return lu * self.dx_m / self.dt_s

    def acceleration(self, m_s2: float) -> float:
        return m_s2 * self.dt_s**2 / self.dx_m

    def acceleration_phys(self, lu: float) -> float:
        return lu * self.dx_m / self.dt_s**2

    def viscosity(self, m2_s: float) -> float:
        """Kinematic viscosity; ``tau = 3 viscosity + 1/2``."""
        return m2_s * self.dt_s / self.dx_m**2

    def viscosity_phys(self, lu: float) -> float:
        return lu * self.dx_m**2 / self.dt_s

    def flow_rate(self, m3_s: float) -> float:
        return m3_s * self.dt_s / self.dx_m**3

    def flow_rate_phys(self, lu: float) -> float:
        return lu * self.dx_m**3 / self.dt_s

    def angular_velocity(self, rad_s: float) -> float:
        return rad_s * self.dt_s

    def angular_velocity_phys(self, lu: float) -> float:
        return lu / self.dt_s

    def density(self, kg_m3: float) -> float:
        return kg_m3 / self.rho_kg_m3

    def density_phys(self, lu: float) -> float:
        return lu * self.rho_kg_m3

    def mass(self, kg: float) -> float:
        return kg / self.mass_scale

    def mass_phys(self, lu: float) -> float:
        return lu * self.mass_scale

    def force(self, n: float) -> float:
        return n * self.dt_s**2 / (self.mass_scale * self.dx_m)

    def force_phys(self, lu: float) -> float:
        return lu * self.mass_scale * self.dx_m / self.dt_s**2

    def torque(self, n_m: float) -> float:
        return n_m * self.dt_s**2 / (self.mass_scale * self.dx_m**2)

    def torque_phys(self, lu: float) -> float:
        return lu * self.mass_scale * self.dx_m**2 / self.dt_s**2

    def moment_of_inertia(self, kg_m2: float) -> float:
        return kg_m2 / (self.mass_scale * self.dx_m**2)

    def moment_of_inertia_phys(self, lu: float) -> float:
        return lu * self.mass_scale * self.dx_m**2

    def pressure(self, pa: float) -> float:
        """Pressure (or stress) difference. The lattice equation of state is ``p = rho c_s^2``
        (Eq. (5, 6)), so a lattice density deviation ``drho`` is ``pressure_phys(drho / 3)``."""
        return pa * self.dt_s**2 / (self.mass_scale / self.dx_m)

    def pressure_phys(self, lu: float) -> float:
        return lu * (self.mass_scale / self.dx_m) / self.dt_s**2


@dataclass(frozen=True)
class LatticeParams:
    """Lattice parameters derived from a scene by :func:`derive` (all in lattice units unless the
    name says otherwise)."""

    units: Units
    shape: tuple[int, int, int]  # fluid domain extent in nodes (x, y, z)
    nu_lu: float
    tau: float
    relaxation: Relaxation  # the collision operator with its rates omega (= 1/tau) and omega_minus
    u_mean_lu: float
    u_max_lu: float
    mach_max: float  # u_max_lu / c_s
    reynolds: float
    accel_lu: tuple[float, float, float]
    flow_rate_lu: float | None
    wall_velocities_lu: dict[str, tuple[float, float, float]]
    n_steps: int
    spinup_steps: int
    sample_every: int
    estimated_seconds: float
    # Additions beyond the shared contract (all with defaults):
    fluid_nodes: int = 0  # nodes whose centre is inside the fluid (pipe: inside the circle)
    char_length_lu: float = 0.0  # length used in `reynolds`
    u_max_basis: str = ""  # which estimate gave u_max (printed by `lbmpipe check`)
    warnings: tuple[str, ...] = field(default=())

    @property
    def omega(self) -> float:
        """Even-moment (viscous) relaxation rate ``1 / tau``."""
        return self.relaxation.omega

    @property
    def omega_minus(self) -> float:
        """Odd-moment relaxation rate (TRT); equals ``omega`` for BGK."""
        return self.relaxation.omega_minus


def _floor_sig(x: float, digits: int = 3) -> float:
    """Round ``x > 0`` down to ``digits`` significant digits, so a suggested limit stays safe."""
    if x <= 0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return math.floor(x / scale * (1 + 1e-12)) * scale


def _ceil_sig(x: float, digits: int = 3) -> float:
    if x <= 0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return math.ceil(x / scale * (1 - 1e-12)) * scale


def nodes_along(extent_mm: float, dx_mm: float) -> int:
    """Number of nodes spanning ``extent_mm`` (the scene validator guarantees a near-integer)."""
    return int(round(extent_mm / dx_mm))


def physical_viscosity(scene) -> float:
    """Kinematic viscosity in m^2/s: given, or from ``Re = U_mean D / nu`` with ``U_mean = Q / A``."""
    fluid = scene.fluid
    if fluid.viscosity_m2_s is not None:
        return fluid.viscosity_m2_s
    d_m = scene.domain.diameter_mm * 1e-3
    u_mean = scene.driving.flow_rate_m3_s / (math.pi * d_m**2 / 4.0)
    return u_mean * d_m / fluid.reynolds


#: Stokes-drag estimate of a periodic box with fixed bodies: peak over superficial speed
STOKES_PEAK_FACTOR = 2.0


def _fixed_bodies(scene: "Scene", shape: tuple[int, int, int]) -> tuple[int, float, float]:
    """(count, sum of volume-equivalent diameters, total volume) of the scene's fixed particles,
    lattice units; groups given by concentration count as ``lbmpipe.particles.placement`` places them."""
    ps = scene.particles
    if ps is None:
        return 0, 0.0, 0.0
    dx = scene.numerics.dx_mm
    box = float(shape[0] * shape[1] * shape[2])

    def vol(p) -> float:
        kind, h = scene_shape(p.shape, p.diameter_mm, p.length_mm, p.edge_mm)
        return volume(kind, h / dx)

    n, d_sum, v_sum = 0, 0.0, 0.0
    for p in [b for b in ps.bodies if b.fixed] + [g for g in ps.random if g.fixed]:
        v = vol(p)
        k = 1 if not hasattr(p, "count") else (p.count or max(1, int(round(p.concentration * box / v))))
        n += k
        d_sum += k * (6.0 * v / math.pi) ** (1.0 / 3.0)
        v_sum += k * v
    return n, d_sum, v_sum


def _expected_velocities(
    scene, shape: tuple[int, int, int], nu_lu: float, accel_lu: tuple[float, float, float],
    flow_rate_lu: float | None, wall_velocities_lu: dict[str, tuple[float, float, float]], n_steps: int,
) -> tuple[float, float, float, str]:
    """(u_mean, u_max, characteristic length, basis) of the expected flow, lattice units; basis
    names the estimate behind ``u_max``.

    Box: ``u_max`` is an upper bound (plane Poiseuille across the narrowest walled gap plus the
    fastest wall), ``u_mean`` the plane-flow estimate (2/3 of the Poiseuille maximum, half of
    each wall speed). Along an axis with no wall across it, fixed particles hold the flow back:
    their Stokes drag balances the body force, ``g V = 3 pi nu U sum(d_i)`` with ``d_i`` the
    volume-equivalent diameters (an upper bound on the superficial speed ``U``: the sphere has
    the least Stokes drag of all bodies of its volume, and neighbours raise the drag of each body,
    Hasimoto's periodic arrays); the peak is taken as ``STOKES_PEAK_FACTOR U / (1 - phi)``, and
    no higher than free acceleration ``g T``. This is an estimate, not a bound; the run-time guard
    (``lbmpipe.guard``) watches the real speed. With nothing to resist, free acceleration ``g T``.

    Half-way bounce-back puts walls half a link outside the outermost fluid nodes, so a pipe of
    ``n_d`` nodes has radius ``n_d / 2`` and a channel of ``n`` nodes has width ``n``.
    """
    dom = scene.domain
    kind = scene.driving.kind
    if dom.kind == "pipe":
        radius = shape[0] / 2.0
        if kind == "flow_rate":
            u_mean = flow_rate_lu / (math.pi * radius**2)
            return u_mean, 2.0 * u_mean, 2.0 * radius, "Poiseuille centre line 2 Q / A"
        if kind == "body_force":
            u_max = abs(accel_lu[2]) * radius**2 / (4.0 * nu_lu)  # Hagen-Poiseuille
            return u_max / 2.0, u_max, 2.0 * radius, "Hagen-Poiseuille centre line g R^2 / (4 nu)"
        return 0.0, 0.0, 2.0 * radius, "no driving"

    walled = [a for a, axis in enumerate("xyz") if getattr(dom.walls, axis) == "wall"]
    char_len = float(min(shape[a] for a in walled)) if walled else float(min(shape))
    u_force_sq = 0.0
    mean_vec = [0.0, 0.0, 0.0]
    basis: list[str] = []
    n_fixed, d_sum, v_fixed = _fixed_bodies(scene, shape)
    if kind == "body_force":
        for a in range(3):
            g = accel_lu[a]
            if g == 0.0 or a in walled:  # a force normal to walls is balanced by pressure
                continue
            across = [shape[b] for b in walled if b != a]
            if across:
                # Plane Poiseuille across the narrowest walled gap bounds any duct flow from above.
                u_a = abs(g) * min(across) ** 2 / (8.0 * nu_lu)
                mean_vec[a] += math.copysign(2.0 / 3.0 * u_a, g)
                basis.append(f"{'xyz'[a]}: plane Poiseuille g H^2 / (8 nu) across the narrowest walled gap")
            else:
                u_free = abs(g) * n_steps  # nothing resists: uniform acceleration until the end of the run
                box = float(shape[0] * shape[1] * shape[2])
                u_stokes = abs(g) * (box - v_fixed) / (3.0 * math.pi * nu_lu * d_sum) if d_sum > 0 else math.inf
                u_peak = STOKES_PEAK_FACTOR * u_stokes / max(1.0 - v_fixed / box, 1e-3)
                if u_peak < u_free:
                    u_a = u_peak
                    mean_vec[a] += math.copysign(u_stokes, g)
                    basis.append(f"{'xyz'[a]}: Stokes drag of the {n_fixed} fixed particle(s) balancing the body force, "
                                 f"peak {STOKES_PEAK_FACTOR:g} U / (1 - phi) (an estimate; the run-time guard checks the speed)")
                else:
                    u_a = u_free
                    mean_vec[a] += math.copysign(u_a, g)
                    basis.append(f"{'xyz'[a]}: free acceleration g T over the run (nothing resists)")
            u_force_sq += u_a**2
    for v in wall_velocities_lu.values():
        # Each sliding face drives a linear (Couette) profile falling to 0 at the opposite face.
        for a in range(3):
            mean_vec[a] += 0.5 * v[a]
    u_walls = max((math.sqrt(sum(c * c for c in v)) for v in wall_velocities_lu.values()), default=0.0)
    # Stokes flows superpose, so the sum bounds the centre-line speed of the combined flow.
    u_max = math.sqrt(u_force_sq) + u_walls
    u_mean = math.sqrt(sum(c * c for c in mean_vec))
    if u_walls:
        basis.append("fastest moving wall")
    return u_mean, u_max, char_len, " + ".join(basis) or "no driving"


def derive(scene) -> LatticeParams:
    """Lattice parameters of ``scene`` (a validated ``lbmpipe.scene.Scene``); raises SceneError
    when they make the run meaningless."""
    num, dom, run = scene.numerics, scene.domain, scene.run
    units = Units(num.dx_mm * 1e-3, num.dt_s, scene.fluid.density_kg_m3)
    if dom.kind == "pipe":
        n_d = nodes_along(dom.diameter_mm, num.dx_mm)
        shape = (n_d, n_d, nodes_along(dom.length_mm, num.dx_mm))
    else:
        shape = tuple(nodes_along(s, num.dx_mm) for s in dom.size_mm)

    nu_phys = physical_viscosity(scene)
    nu_lu = units.viscosity(nu_phys)
    tau = nu_lu / CS2 + 0.5
    visc_field = "fluid.reynolds" if scene.fluid.reynolds is not None else "fluid.viscosity_m2_s"
    if not tau > 0.5:
        dt_ok = _ceil_sig((TAU_MARGINAL - 0.5) * CS2 * units.dx_m**2 / nu_phys) if nu_phys > 0 else math.inf
        raise SceneError(
            "numerics.dt_s",
            f"tau = {tau:.6g} <= 1/2: the lattice viscosity ({nu_lu:.3g}, from {visc_field}) is "
            "negative or zero, so the BGK/TRT relaxation is unstable",
            f"increase numerics.dt_s to at least {dt_ok:.3g} s (tau = {TAU_MARGINAL}) or increase the viscosity",
        )
    relaxation = Relaxation.from_tau(num.collision, tau, num.trt_magic)

    drv = scene.driving
    accel_lu = tuple(units.acceleration(a) for a in drv.acceleration_m_s2) if drv.kind == "body_force" else (0.0, 0.0, 0.0)
    flow_rate_lu = units.flow_rate(drv.flow_rate_m3_s) if drv.kind == "flow_rate" else None
    wall_velocities_lu = {
        mw.side: tuple(units.velocity(v) for v in mw.velocity_m_s) for mw in dom.moving_walls
    }

    n_steps = int(round(units.time(run.duration_s)))
    spinup_steps = int(round(units.time(run.spinup_s)))
    sample_every = max(1, int(round(units.time(run.sample_interval_s))))
    if n_steps < 1:
        raise SceneError(
            "run.duration_s",
            f"duration {run.duration_s:g} s is less than one time step of numerics.dt_s = {num.dt_s:g} s",
            f"set run.duration_s to at least {num.dt_s:g} s",
        )
    if spinup_steps >= n_steps:
        raise SceneError(
            "run.spinup_s",
            f"spin-up {run.spinup_s:g} s rounds to {spinup_steps} steps, not fewer than the "
            f"{n_steps} steps of run.duration_s = {run.duration_s:g} s, leaving nothing to average",
            "lower run.spinup_s or raise run.duration_s",
        )

    u_mean, u_max, char_len, basis = _expected_velocities(
        scene, shape, nu_lu, accel_lu, flow_rate_lu, wall_velocities_lu, n_steps
    )
    mach = u_max / CS
    reynolds = u_mean * char_len / nu_lu if dom.kind == "pipe" else u_max * char_len / nu_lu
    if mach > num.mach_limit:
        # At fixed physical velocities and viscosity every lattice velocity scales with dt.
        dt_ok = _floor_sig(num.dt_s * num.mach_limit / mach)
        tau_ok = 0.5 + (tau - 0.5) * dt_ok / num.dt_s
        raise SceneError(
            "numerics.dt_s",
            f"Mach {mach:.3g} exceeds numerics.mach_limit {num.mach_limit:g} (expected "
            f"u_max = {u_max:.3g} lattice units from {basis})",
            f"reduce numerics.dt_s to <= {dt_ok:.3g} s (keeps Re; tau becomes {tau_ok:.3g}), "
            "or raise numerics.mach_limit to accept the compressibility error (~Ma^2)",
        )

    warnings: list[str] = []
    for name, seconds, steps in (
        ("run.duration_s", run.duration_s, n_steps),
        ("run.spinup_s", run.spinup_s, spinup_steps),
        ("run.sample_interval_s", run.sample_interval_s, sample_every),
    ):
        if abs(units.time_phys(steps) - seconds) > 1e-6 * max(seconds, num.dt_s):
            warnings.append(f"{name} = {seconds:g} s is not a multiple of dt; using {steps} steps "
                            f"({units.time_phys(steps):g} s)")
    bgk = relaxation.operator is CollisionOperator.BGK
    if bgk and tau < TAU_MARGINAL:
        warnings.append(f"tau = {tau:.4g} is close to 1/2: BGK is marginally stable there; "
                        "consider collision: trt or a larger dt_s")
    has_walls = dom.kind == "pipe" or any(getattr(dom.walls, a) == "wall" for a in "xyz")
    if bgk and num.wall == "bounce_back" and has_walls and tau > 1.5:
        warnings.append(
            f"BGK with half-way bounce-back puts the effective wall at a tau-dependent position "
            f"(exact for Poiseuille flow only at Lambda = (tau-1/2)^2 = 3/16, tau = 0.933; here "
            f"Lambda = {(tau - 0.5) ** 2:.3g}); collision: trt with trt_magic 0.1875 makes it tau-independent")
    if mach > DEFAULT_MACH_LIMIT:
        warnings.append(f"Mach {mach:.3g} is above the default limit {DEFAULT_MACH_LIMIT} (numerics.mach_limit "
                        f"raised to {num.mach_limit:g}): compressibility errors of order Ma^2 = {mach**2:.2g}")

    params = LatticeParams(
        units=units, shape=shape, nu_lu=nu_lu, tau=tau, relaxation=relaxation,
        u_mean_lu=u_mean, u_max_lu=u_max, mach_max=mach, reynolds=reynolds, accel_lu=accel_lu,
        flow_rate_lu=flow_rate_lu, wall_velocities_lu=wall_velocities_lu, n_steps=n_steps,
        spinup_steps=spinup_steps, sample_every=sample_every, estimated_seconds=0.0,
        fluid_nodes=cost.fluid_nodes(dom.kind, shape), char_length_lu=char_len, u_max_basis=basis,
        warnings=tuple(warnings),
    )
    return replace(params, estimated_seconds=cost.estimate_seconds(params, threads=run.threads))
