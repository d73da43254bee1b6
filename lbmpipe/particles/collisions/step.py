"""The collision step: ``resolve_collisions``, called once per time step, after the velocity
update (hydrodynamic forces) and before the positions are advanced, and its kernel
(``_resolve_kernel``), which runs the stages in order:

1. ``narrow_phase.step_pairs``: the candidate pairs from the Verlet list kept between calls;
2. ``narrow_phase.measure_contacts``: signed gaps, normals and points of pairs and walls;
3. ``impulse_rounds.impulse_rounds``: the impulses of Eqs. (16)-(21) (``impulse``), with
   speculative contacts (``toi``) and the lock of jams (``jam``);
4. ``projection.project_overlaps``: the overlaps left are projected away.

Overlap bound (``OVERLAP_BOUND_FACTOR``; ``CollisionParams.overlap_bound``, which the run-time
guard enforces). When ``resolve_collisions`` returns, every pair and wall overlap is
``<= overlap_tol`` (default 0.01 lattice spacing) unless both projections ran out of iterations;
the value reached is ``stats["max_overlap_after"]`` either way. At any time, before a call or
after it, overlaps stay within ``overlap_bound = OVERLAP_BOUND_FACTOR * overlap_tol`` (0.1
lattice spacing). Every source of overlap, with what holds it:

1. what a call leaves: ``<= overlap_tol``, more only in a jam that exhausts
   ``max_projection_iters`` (reported as ``max_overlap_after``);
2. the drift after a call, of contacts the free-motion prediction covers: a speculative contact
   bounces within ``_TOI_TOL`` (1e-3) of touching; a touching contact is held at its present point
   and, if its bodies turn by more than half of its gap plus half the overlap bound at their
   bounding radii, its twin takes the speculative test (c), so other features turning into contact
   add at most half the overlap bound plus second order in the angle (a slack of ``overlap_tol``
   instead sent nearly every touching contact of 244 dense cylinders, turning by ~1e-3 rad a
   step, to the test, and doubled the cost per contact);
3. contacts left approaching at the sweep caps: ``stats["unresolved"]``; the last half of the
   sweeps are inelastic, which settles the jams that bounce without end at ``k = 1``, and a jam
   still approaching at the cap is locked (``_lock_jams``, ``stats["locked_bodies"]``): the bodies
   its approaching pairs join move on as one rigid body with their linear and angular momentum (a
   cluster with a body approaching a wall stops), so none of its contacts approaches in the drift,
   and inelastic sweeps then take up what the locked bodies' new velocities do to their other
   contacts (a row of cubes spinning at 0.09 rad a step jammed in a channel, and a dense box at
   ``contact_gap`` 1.0, turned 0.17-0.22 lu into each other without it; the box blew up). The
   paper's suspensions leave none unresolved at dx = 1 mm. At dx = 2 mm the dense 8 x 16 mm
   cylinders do (51-362 contacts in 4,000 steps), and there the overlap before a call reaches
   0.10-0.13 lu (0.09-0.12 without the lock): a fluid-coupled jam that the bound does not hold
   (``stats["max_overlap_before"]`` reports it; without the sweeps after the lock, 0.29 lu);
4. motion the prediction does not see: the next step's force and torque kicks (the call comes
   after the velocity update, so only the drift's own change of the rotation axis of
   non-symmetric bodies is left within a step) and the projection's pushes into contacts it has
   not listed (a pass with a fresh pair list follows any push beyond half the skin).

Each is removed again at the next call. The dry-run tests (200 spheres and cubes, 10^4 steps,
speeds ~0.1 and spins ~0.1 rad per step; a dense box of spheres, cubes and cylinders spinning at
0.05 rad per step) assert ``overlap_bound`` before each call and ``overlap_tol`` after it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ...errors import SceneError, Unstable
from ..contact import bounding_radii
from ..rigid import Bodies, quat_to_matrices
from ..collision_params import CollisionParams, Domain, min_periodic_length
from .bundles import _NSTATS, _S_CAND, _S_DISP, _S_IMP, _S_LOCK, _S_OVA, _S_OVB, _S_PAIR, _S_PROJ, _S_ROT, _S_SWEEP
from .bundles import _S_UNRES, _S_WALL, BodyArrays, BodyTerms, DomainArrays, StepParams, VerletArrays
from .impulse_rounds import impulse_rounds
from .narrow_phase import NeighbourList, measure_contacts, step_pairs
from .projection import project_overlaps

_min_periodic_length = njit(cache=True, inline="always")(min_periodic_length)


@njit(cache=True)
def _step_bodies(B):
    """Stage 0 of the step: the bodies' per-step terms (``BodyTerms``) and the fastest point
    speed of a movable body.

    Input: bodies B (``BodyArrays``). Outputs: (T, vmax): T.Rm the rotation matrices of q, T.rb the
    bounding radii, T.im = 1/m and T.iinv = 1/J (principal, body frame; 0 for a fixed body:
    infinite mass and inertia), T.sweep = |v| + |wb| r_b (lattice spacings per step), vmax the
    largest sweep of a movable body. Reads only."""
    kind, h, mass, inertia, x, v, q, wb, fixed = B
    n = x.shape[0]
    Rm = quat_to_matrices(q)
    rb = bounding_radii(kind, h)
    im = np.zeros(n)
    iinv = np.zeros((n, 3))
    for i in range(n):
        if not fixed[i]:
            im[i] = 1.0 / mass[i]
            for k in range(3):
                iinv[i, k] = 1.0 / inertia[i, k]
    sweep = np.empty(n)  # fastest point speed |v| + |omega| r_b of each body
    vmax = 0.0
    for i in range(n):
        sp = math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
        sp += math.sqrt(wb[i, 0] ** 2 + wb[i, 1] ** 2 + wb[i, 2] ** 2) * rb[i]
        sweep[i] = sp
        if not fixed[i]:
            vmax = max(vmax, sp)
    return BodyTerms(Rm, rb, im, iinv, sweep), vmax


@njit(cache=True)
def _periodic_status(rb, lo, hi, periodic, contact_gap, skin, reach):
    """0 if every periodic length holds two interaction ranges (``min_periodic_length``) of the
    largest body, else the status the caller raises on: 1 + axis if the geometry itself does
    not fit, 4 + axis if only the speculative ``reach`` (lattice spacings) is too long. A periodic
    axis shorter than that would let a pair meet two images. Checked in the kernel rather than
    with NumPy before the call: run cold after the fluid sweep, those calls took 0.15 ms a step."""
    rbmax = 0.0
    for i in range(rb.shape[0]):
        rbmax = max(rbmax, rb[i])
    for a in range(3):
        if periodic[a] and (hi[a] - lo[a]) < _min_periodic_length(rbmax, contact_gap, skin):
            return 1 + a
    for a in range(3):
        if periodic[a] and (hi[a] - lo[a]) < _min_periodic_length(rbmax, reach, skin):
            return 4 + a
    return 0


@njit(cache=True)
def _resolve_kernel(B, D, P, V, stats):
    """One pass of the collision step (``resolve_collisions`` makes up to four; the first applies
    impulses, the others only project).

    Inputs (lattice units: lengths in lattice spacings, times in steps): bodies B
    (``BodyArrays``), domain D (``DomainArrays``), parameters P (``StepParams``; ``P.dt`` the time
    step), Verlet list V (``VerletArrays``), stats (``_NSTATS``,) float, accumulated in place.
    Outputs: (maxdisp, V, status): the largest displacement bound of a body in the projection, the
    Verlet list (a new one if rebuilt), and 0, or the periodic-length status of
    ``_periodic_status`` (then nothing has been changed). In place: B.v, B.wb (impulses), B.x, B.q
    (projection). Invariants: the result does not depend on the thread count nor on whether the
    Verlet list was fresh; linear momentum is conserved by the impulses (walls and fixed bodies
    aside)."""
    T, vmax = _step_bodies(B)
    # gap below which a contact can become active within this step
    reach = P.contact_gap + (2.0 * vmax * P.dt if P.spec else 0.0)
    margin = reach + P.skin
    if P.do_impulses and P.pairs:
        # Without a pair search (one body, or pairs off) a body meets only the walls: no rule.
        status = _periodic_status(T.rb, D.lo, D.hi, D.periodic, P.contact_gap, P.skin, reach)
        if status:
            return 0.0, V, status
    pi, pj, ps, pk, V = step_pairs(B.x, T.rb, margin, D.lo, D.hi, D.periodic, P.list_skin, P.pairs, V)
    C = measure_contacts(B, T, D, P, pi, pj, ps, pk, V.win, margin, reach, stats)
    if P.do_impulses:
        impulse_rounds(B, T, C, D, P, vmax, reach, stats)
    maxdisp = project_overlaps(B, T, C, D, P, margin, stats)
    return maxdisp, V, 0


def resolve_collisions(bodies: Bodies, domain: Domain, params: CollisionParams, dt: float, pairs: bool = True,
                       step: int = -1, nlist: NeighbourList | None = None) -> dict:
    """Detect all particle-particle and particle-wall contacts, apply the impulses of
    Eqs. (16)-(21) (in place on ``bodies.v`` and ``bodies.wb``) and project overlaps away (in place
    on ``bodies.x``). The model: the package's modules (``impulse``, ``toi``, ``impulse_rounds``,
    ``jam``, ``projection``); the overlap bound: this module's docstring.

    Returns stats: ``candidates`` (broad-phase pairs), ``pair_contacts`` and ``wall_contacts``
    (gap <= contact_gap), ``impulses`` (applied), ``max_overlap_before`` (largest overlap seen
    before the projection), ``max_overlap_after`` (after it; <= overlap_tol unless the projection
    was exhausted), ``sweeps``, ``projection_iters``, ``unresolved`` (contacts still approaching
    after max_sweeps), ``max_displacement`` (largest projection shift of a body), ``passes``.
    ``pairs=False`` skips the broad phase and all particle-particle contacts (walls only).
    Raises ``errors.Unstable`` (naming ``step``) when a body moves so fast that its reach per step
    spans the periodic length: the sign of a run that has blown up between guard checks.
    ``nlist``: the pair search's Verlet list, to keep between calls (time steps); None: a fresh one
    (the same result, at the cost of a new list).
    """
    n = bodies.n
    stats = np.zeros(_NSTATS)
    if n == 0:
        return _stats_dict(stats, 0)
    D = DomainArrays(*domain.arrays())
    lo, hi = D.lo, D.hi
    B = BodyArrays(bodies.kind, bodies.h, bodies.mass, bodies.inertia, bodies.x, bodies.v, bodies.q, bodies.wb,
                   bodies.fixed)
    P = StepParams(float(params.restitution), float(params.contact_gap), bool(params.speculative),
                   float(params.overlap_tol), float(params.manifold_tol), float(params.skin), int(params.max_sweeps),
                   int(params.max_projection_iters), int(params.translation_iters), float(dt),
                   float(params.list_skin), float(params.rest_speed), True, bool(pairs))
    if nlist is None:
        nlist = NeighbourList()
    if nlist.xref.shape[0] != n:
        nlist.xref = np.zeros((n, 3))
        nlist.meta[0] = 0.0
    passes = 0
    for p in range(4):
        V = VerletArrays(nlist.start, nlist.js, nlist.win, nlist.xref, nlist.meta)
        maxdisp, V, status = _resolve_kernel(B, D, P._replace(do_impulses=p == 0), V, stats)
        nlist.start, nlist.js, nlist.win = V.start, V.js, V.win
        if status:
            _refuse(status, bodies, params, lo, hi, step)
        passes += 1
        # bodies pushed further than half the skin may meet pairs outside the list: rebuild it
        if maxdisp <= 0.5 * params.skin:
            break
    return _stats_dict(stats, passes)


def _refuse(status: int, bodies: Bodies, params: CollisionParams, lo, hi, step: int):
    """Raise the error of a kernel status (``_resolve_kernel`` has left the bodies untouched)."""
    a = (status - 1) % 3
    rb = bounding_radii(bodies.kind, bodies.h)
    if status <= 3:
        # a SceneError is a ValueError; lbmpipe check applies the same rule first
        need = min_periodic_length(float(np.max(rb)), params.contact_gap, params.skin)
        raise SceneError(
            "domain", f"periodic length {hi[a] - lo[a]:g} along axis {'xyz'[a]} is shorter than two interaction "
            f"ranges in lattice spacings (2 x {need / 2:g}): a pair would interact with two images",
            f"make the domain at least {need:g} lattice spacings long along that axis, or set "
            "particles.collisions.pairs: false")
    # The geometry fits; only the speculative reach of a body moving many lattice spacings per
    # step does not. No physical suspension does that: it is a blown-up run, so report it as one
    # (the guard's status 'unstable') rather than as a bad domain.
    speed = np.linalg.norm(bodies.v, axis=1) + np.linalg.norm(bodies.wb, axis=1) * rb
    k = int(np.argmax(np.where(~bodies.fixed, speed, -1.0)))
    raise Unstable(f"particle speed {speed[k]:.3g} lattice units per step (translation plus rotation at the "
                   f"bounding radius) reaches past the periodic images", f"particle {k}", step,
                   "the fluid-particle coupling went unstable (high Mach number or a thin fluid film)",
                   "reduce numerics.dt_s, use numerics.collision: trt, or lower the concentration")


def _stats_dict(stats: np.ndarray, passes: int) -> dict:
    return {
        "candidates": int(stats[_S_CAND]),
        "pair_contacts": int(stats[_S_PAIR]),
        "wall_contacts": int(stats[_S_WALL]),
        "impulses": int(stats[_S_IMP]),
        "max_overlap_before": float(stats[_S_OVB]),
        "max_overlap_after": float(stats[_S_OVA]),
        "sweeps": int(stats[_S_SWEEP]),
        "projection_iters": int(stats[_S_PROJ]),
        "unresolved": int(stats[_S_UNRES]),
        "max_displacement": float(stats[_S_DISP]),
        "rotation_projections": int(stats[_S_ROT]),
        "locked_bodies": int(stats[_S_LOCK]),
        "passes": int(passes),
    }


