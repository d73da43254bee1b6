"""Contact detection between cylinders, cubes and spheres, and between a body and the walls.

This supplies what the impulse model of Eqs. (16)-(21) needs from geometry: for two bodies the
signed gap, the unit normal ``p`` pointing from body 1 to body 2, and the contact point ``O``
(lab frame); for a body and a wall the same with the wall as body 2 (``p`` points from the body
into the wall).

Narrow phase (``body_contact``)
-------------------------------
- sphere-sphere: exact, from the centre distance;
- cylinder-cylinder, separated: exact, without GJK (``cylinder_gap_exact``). The closest points
  of two cylinders lie on one of five feature pairs: side-side (the closest points of the two
  axes: closed form), a cap against the other body (that body's support point along the cap's
  normal, projected onto the cap: closed form), rim-side and rim-rim (one angle on the rim, by
  Newton's method from the best of 8 samples: the squared distance of a rim point to the other
  axis is a trigonometric polynomial of degree 2). Candidates are tried from the cheapest, and
  each is certified: its length ``|b - a|`` bounds the gap from above, the separation of the two
  support heights along ``(b - a)/|b - a|`` bounds it from below, and the first candidate whose
  two bounds meet within ``1e-9`` of the body size (GJK's own stopping rule) is the gap. An
  uncertified pair (overlapping, touching, or a configuration the candidates miss: none of the
  1,587 random separated pairs of the paper's shapes in the tests) goes to GJK/EPA below;
- sphere-X: GJK between the sphere's centre (a point) and X, then the sphere radius is
  subtracted (exact, and GJK on a point converges fast); falls back to the general path if the
  centre is inside X;
- general: GJK (Gilbert-Johnson-Keerthi, closest point of the Minkowski difference
  ``D = A - B`` to the origin, simplex sub-problems by Voronoi regions as in Ericson,
  *Real-Time Collision Detection*, 5.1) on the support functions of ``lbmpipe.particles.shapes``; if the
  bodies overlap, EPA (expanding polytope) gives the penetration depth and normal, i.e. the
  smallest translation of body 2 that separates them.
- signed gap: ``+distance`` when separated, ``-depth`` when overlapping. Accuracy: GJK stops when
  the gap is bracketed to ``1e-9`` of the body size, EPA when its support gap is below ``1e-7``
  of the body size, at ``EPA_MAX_VERTS`` vertices (curved surfaces converge slowly in EPA) or
  when its face table (``EPA_MAX_FACES``) cannot hold a step's new faces, with the closest face
  found so far.
  Against an independent separating-axis maximisation the signed gap agrees to ``1e-5`` (tests,
  bodies of size ~2-4). On curved surfaces the normal is less accurate than the gap (an error
  ``e`` in the gap allows ~``sqrt(e * curvature radius)`` in the normal: ~1e-4 rad here).

Contact point. GJK/EPA return one witness point per body. Where flat features meet (cube face on
cube face, cylinder side on cylinder side, cap on face...) the witness is an arbitrary point of the
contact patch, and an impulse there would spin the bodies spuriously. So the contact point is the
centroid of the contact patch: the support features of both bodies along the normal (vertex, edge,
face of a cube; rim point, side segment or cap disc (a 16-gon) of a cylinder), taken within
``manifold_tol`` of the extreme, are projected onto the contact plane and intersected; the centroid
of that convex polygon (or the midpoint of the overlap of two segments) is the in-plane position of
``O``; its normal coordinate is the midpoint of the witness points. ``manifold_tol`` is a length
(default in the callers: 0.1 lattice spacing): a face tilted so that its far edge is within it of the
near edge counts as flat.

Cost. The dense 8 x 8 mm cylinders at 50 % (244 bodies in the paper's pipe) give ~1,050-1,200
candidate pairs per step, ~800 of them within the collision model's contact gap of one lattice
spacing, where GJK takes ~20 iterations on the curved surfaces; the exact cylinder path takes a
fraction of GJK's time for the same pairs (figures: benchmarks/README.md). Inside these loops
nothing allocates, and arrays are made and passed sparingly: each view, and each array passed to
a function, costs a reference count, ~10-20 ns. The simplex rows go to ``_closest_triangle`` as
scalars; the scratch is one buffer (``new_scratch``), whose views are made only on the path that
needs them (a tuple of its 18 arrays cost ~0.4 us per call, more than half of a cylinder
contact); where one feature is a rim point the contact point is written out instead of making
the patch's views; beyond ``max_gap`` there is no patch.

Walls
-----
- pipe wall (``pipe_wall_contact``), a cylinder of radius ``R`` about the axis through
  ``(cx, cy)`` along z: gap = ``R - max`` distance of a body point from the axis. Exact per shape:
  sphere from its centre; cube from its 8 vertices (a convex function is maximised at a vertex);
  cylinder from its two rim circles, each sampled at 32 angles and every local maximum refined by
  Newton's method on ``rho^2(theta)``. Where several points are within ``manifold_tol`` of the
  maximum (a cube face or cylinder side lying against the wall, a cap facing the wall) the contact
  point is their mean and the normal the radial unit vector through it, so a symmetric contact
  applies no torque.
- planar walls (``plane_wall_contact``) at ``x = c`` with outward side ``+-1``: gap from the support
  point; contact point the centroid of the support feature.

Broad phase (``candidate_pairs``)
---------------------------------
Cell list on bounding spheres (cells of edge ``2 max r_b + margin``), so the cost is linear in
the number of bodies; periodic axes wrap the cells and the pair gets the minimum-image shift
``s`` (body 2 is at ``x_2 + s``). A periodic length must be at least two cells. Over time steps
the collision step keeps a Verlet list (``neighbour_list``, a wider margin) and takes each step's
pairs from it (``listed_pairs``: the cell scan's pairs in the cell scan's order) until a body has
moved by half the extra margin.

Modules
-------
``support`` (support points, vector helpers, disc and rim discretisation), ``gjk``, ``epa``,
``features`` (contact features and the patch centroid), ``scratch`` (the narrow phase's scratch
buffer), ``cylinders`` (exact cylinder-cylinder contact), ``narrow`` (``body_contact``), ``walls``,
``broad`` (cell scan, Verlet list), ``convenience`` (Python entry points for tests and set-up).
This package re-exports their public names.
"""

from .support import DISC_SIDES, RIM_SAMPLES, support3
from .gjk import GJK_MAX_ITER, GJK_REL_TOL
from .epa import EPA_MAX_FACES, EPA_MAX_VERTS, EPA_REL_TOL
from .scratch import WS_HINT, WS_SIZE, WS_WON, new_scratch, ws_rows
from .cylinders import cylinder_gap_exact, cylinders_overlap_exact
from .narrow import bodies_overlap_ws, body_contact, body_contact_ws
from .walls import pipe_wall_contact, plane_wall_contact
from .broad import bounding_radii, candidate_pairs, list_displacement, listed_pairs, listed_slots, neighbour_list
from .convenience import contact_pair, contact_pipe, contact_plane

__all__ = [
    "DISC_SIDES", "RIM_SAMPLES", "support3",
    "GJK_MAX_ITER", "GJK_REL_TOL",
    "EPA_MAX_FACES", "EPA_MAX_VERTS", "EPA_REL_TOL",
    "WS_HINT", "WS_SIZE", "WS_WON", "new_scratch", "ws_rows",
    "cylinder_gap_exact", "cylinders_overlap_exact",
    "bodies_overlap_ws", "body_contact", "body_contact_ws",
    "pipe_wall_contact", "plane_wall_contact",
    "bounding_radii", "candidate_pairs", "list_displacement", "listed_pairs", "listed_slots", "neighbour_list",
    "contact_pair", "contact_pipe", "contact_plane",
]
