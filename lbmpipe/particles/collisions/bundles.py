"""The arrays the collision step's stages pass each other, bundled as named tuples (numba
compiles a named tuple of arrays into a struct of them: a field read is free), and the layout of
the stats array the kernels fill. Lattice units throughout: lengths in lattice spacings, times in
time steps, masses in the units of ``Bodies.mass``.

Only the stages of the step (``step``, ``narrow_phase``, ``impulse_rounds``, ``jam``,
``projection``) take bundles; the kernels they call once per contact keep their arrays as
separate arguments, unpacked once per stage: those loops are tuned to the argument (a function
called per contact costs a reference count per array it is handed)."""

from __future__ import annotations

from collections import namedtuple

#: The bodies as the caller holds them (``rigid.Bodies``): shape code (n,) int, half sizes h (n, 3),
#: mass (n,), principal inertia (n, 3), centre x (n, 3), velocity v (n, 3), orientation q (n, 4,
#: body -> lab), body-frame angular velocity wb (n, 3), fixed (n,) bool. ``x``, ``v``, ``q``, ``wb``
#: are changed in place by the step.
BodyArrays = namedtuple("BodyArrays", "kind h mass inertia x v q wb fixed")

#: Per-step quantities of the bodies derived at the start of a call (``step._step_bodies``):
#: rotation matrices Rm (n, 3, 3) of q, bounding radii rb (n,), inverse masses im (n,) and inverse
#: principal inertias iinv (n, 3) (0 for a fixed body), and sweep (n,), the fastest point speed
#: ``|v| + |omega| r_b`` of each body. ``Rm`` is kept in step with ``q`` by the rotating projection.
BodyTerms = namedtuple("BodyTerms", "Rm rb im iinv sweep")

#: ``Domain.arrays()``: code (PIPE / BOX), pipe radius Rp and axis (cx, cy), box or period bounds
#: lo, hi (3,), periodic (3,) bool.
DomainArrays = namedtuple("DomainArrays", "dcode Rp cx cy lo hi periodic")

#: ``CollisionParams`` as numbers, with the call's ``dt`` and switches: ``k_rest`` (restitution),
#: ``contact_gap``, ``spec`` (speculative contacts), ``overlap_tol``, ``manifold_tol``, ``skin``,
#: ``max_sweeps``, ``max_proj`` (max_projection_iters), ``max_trans`` (translation_iters), ``dt``,
#: ``list_skin``, ``vrest`` (rest_speed), ``do_impulses`` (False in the passes after the first,
#: which only project), ``pairs`` (False: walls only).
StepParams = namedtuple("StepParams", "k_rest contact_gap spec overlap_tol manifold_tol skin max_sweeps max_proj "
                                      "max_trans dt list_skin vrest do_impulses pairs")

#: The Verlet list kept between calls (``NeighbourList``): CSR start (n + 1,) and partners js of
#: each body's listed pairs, win (len(js),) int8 the exact cylinder candidate that won last in each
#: slot, xref (n, 3) the positions it was built at, meta (2,): the margin it was built for (0: none
#: yet) and the number of builds.
VerletArrays = namedtuple("VerletArrays", "start js win xref meta")

#: The contacts of one call (``narrow_phase.measure_contacts``). Pairs: bodies pi, pj (npair,),
#: periodic shift ps (npair, 3) of body 2 (at x_j + s), list slot pk (npair,), signed gap cg
#: (npair,), normal cn (npair, 3) from 1 to 2, point cc (npair, 3). Walls: body wi (nwall,), gap
#: wg, normal wn (into the wall), point wc. Gaps above ``contact_gap`` may be lower bounds.
Contacts = namedtuple("Contacts", "pi pj ps pk cg cn cc wi wg wn wc")

#: The impulse rows of one call (``impulse_rounds.impulse_rows``): 2 nc rows, nc = npair + nwall;
#: row m < npair a pair, npair + m a wall, nc + m the twin (c) of touching contact m (a second
#: contact of the same bodies, at the geometry of a time of impact). gn (2 nc, 3) normals, gt
#: (2 nc, ``_NG``) impulse terms (``impulse._pair_terms``), ci, cj (2 nc,) bodies (cj = -1: wall),
#: and their views by kind: gp_n, gw_n, tp_n, tw_n (normals of pairs, walls, pair twins, wall
#: twins), gt_p, gt_w, tt_p, tt_w (terms); points gp_c, gp_c2 (npair, 3: body 1's and body 2's,
#: which differ for speculative contacts), gw_c, and the twins' tp_c, tp_c2, tw_c; active flags
#: on_p, on_w (pairs, walls), on_tp, on_tw (twins).
ImpulseRows = namedtuple("ImpulseRows", "gn gt ci cj gp_n gw_n tp_n tw_n gt_p gt_w tt_p tt_w "
                                        "gp_c gp_c2 gw_c tp_c tp_c2 tw_c on_p on_w on_tp on_tw")

# stats layout
_S_CAND, _S_PAIR, _S_WALL, _S_IMP, _S_OVB, _S_OVA, _S_SWEEP, _S_PROJ, _S_UNRES, _S_DISP, _S_ROT, _S_LOCK = range(12)
_NSTATS = 12
