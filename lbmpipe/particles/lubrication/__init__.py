"""Sub-grid lubrication between close surfaces (``numerics.lubrication``; off by default, the
paper's method).

Why. When two surfaces come within about a lattice spacing no fluid node is left between them,
and the moving bounce-back of Eq. (8) no longer resolves the film: the squeeze force, which grows
without bound as the gap closes, stays at about its value at one spacing. Below the cutoff ``h_c``
the missing part is added from lubrication theory with the part the lattice resolves subtracted
(Nguyen & Ladd 2002, Phys. Rev. E 66, 046708):

    F = -(zeta(h) - zeta(h_c)) u,   zero at and above h_c, continuous there,

with ``zeta`` the resistance of the film for the features that face each other and ``u`` the
relative velocity of the surfaces. Below ``min_gap_dx`` the gap is held at it (saturation):
``zeta`` stays finite and the collision model takes over at contact. The cutoff (``cutoff_dx``,
0.8 spacing) is a property of the particle boundary, not of the physics: like Nguyen & Ladd, and
Rettinger & Ruede (waLBerla, 2/3 spacing), it is calibrated, here on a sphere approaching a wall
(``benchmarks/lubrication.py``: Ladd's bounce-back, tau 1, radii 6 and 8). That staircase surface
resolves the film non-monotonically below a spacing (a one-node film over-resists near a gap of
half a spacing), so no cutoff fits every gap: with 0.8 the force is within 7.5 % of Brenner's from
0.1 to 0.75 spacing (radius 8; within 3.6 % up to 0.3), where 1.0 left up to 19 %.

Model per pair of features (``geometry`` finds the features, ``formulas`` has the resistances). The
collision narrow phase gives the gap ``h``, the normal and the contact point; the features of each
body facing the other are its support features along the normal (``contact.features._feature``,
within the collision model's flatness tolerance 0.1 spacing): a point (sphere, cube vertex,
cylinder rim point), a segment (cube edge, cylinder side) or a face (cube face, cylinder cap).

| pair | approximation | source |
| --- | --- | --- |
| curved-curved (sphere-sphere, sphere-side, side-side crossed, rim-sphere) | Reynolds' squeeze of the quadratic gap, principal curvatures summed: ``12 pi mu (R_x R_y)^1.5 / ((R_x + R_y) h)``; spheres ``6 pi mu (a1 a2/(a1+a2))^2 / h`` | Cox 1974; Nguyen & Ladd 2002 |
| side-side parallel, side-face, edge-face, edge-edge parallel | line contact: the two-dimensional squeeze ``3 sqrt(2) pi mu R^1.5 h^-1.5`` per unit length over the features' overlap (strips along the line; exact for a straight line, and summed with the factor that makes it Cox's result for any curvature along the line) | Reynolds lubrication; Teng, Rallabandi, Stone & Ault 2022, J. Fluid Mech. 938, A30 (finite rods near a wall) |
| curved-face (sphere, vertex, rim on a face) | Cox's point contact with the face flat (``R = a``, ``r_e``) | Cox 1974; Brenner 1961 (sphere-plane limit) |
| edge-edge crossed, vertex-anything | point contact with the edge a cylinder, the vertex a sphere, of radius ``r_e`` | as curved-curved |
| face-face, cap-face, cap-cap (within 0.1 spacing of parallel) | squeeze film between plates of the overlap patch ``A``: ``beta mu A^2 / h^3``, ``beta = 3 A^2/(4 pi^2 I_p)`` (Saint-Venant's torsion integral: exact for discs (Stefan) and ellipses, +8 % for a square); tangential: plane Couette ``mu A / h`` at the patch centroid | Reynolds; Stefan 1874 |
| anything-plane wall | as against a face; a face on the wall: the plate with the face as patch | as above |
| anything-pipe wall (concave, radius ``R_p``) | the wall's curvature ``-1/R_p`` along the azimuth added to the gap's: a sphere ``k = 1/a - 1/R_p`` across; a side along the pipe a line contact; a straight feature across the azimuth has its film thinnest at its ends (strip sum with negative curvature); a face: plate at its mean gap | Cox 1974 with the wall's curvature |

Edges and rims get the radius of curvature ``r_e = edge_radius_dx`` (1 spacing): the bounce-back
surface is a staircase of lattice links, so the fluid sees no feature sharper than a spacing,
and a perfectly sharp edge would make the force depend on its sub-grid shape alone (a wedge's
squeeze force diverges only logarithmically; Cawthorn & Balmforth 2010). The tangential forces of
curved contacts diverge only logarithmically (Goldman, Cox & Brenner 1967; Jeffrey & Onishi 1984)
and couple translation and rotation in forms a contact-point resistance does not represent: they
are left out, as are the twisting and rocking torques of flat patches. A face counts as flat when
it is within 0.1 spacing of parallel; past that the edge model takes over, and the force falls
from the plate's to the edge's (a step a tilted-plate solution would smooth). Each contact is
treated alone: films of several contacts add.

Where the force is applied, and why (``implicit``). The resistance grows like 1/h (curved) to 1/h^3
(flat): an explicit force would overshoot once ``zeta dt`` passes twice the pair's effective mass
(``zeta / m`` reaches 17-47 per step for a sphere of radius 4 at ``min_gap``, tau 0.96-1.78). The
coupling's implicit update solves each particle's own 6 x 6 system and cannot hold a pair's mutual
resistance, so the force is applied after it (phase ``post``, before the collisions and the
drift) as an impulse implicit in the pair's relative velocity at the contact point: unconditionally
stable and dissipative, equal and opposite on the two bodies (momentum and angular momentum
conserved), the same treatment as the impulses of the collision model that follows.

Interplay with collisions: with the paper's ``contact_gap_dx`` of 1 spacing, collisions bounce
particles apart at about the cutoff, so lubrication acts only with a smaller contact gap.

Modules: ``formulas`` (closed-form resistances), ``geometry`` (features, curvature, overlap and
the resistances of one contact), ``implicit`` (the impulses), ``step`` (one step: the narrow
phase's contacts, their resistances, the impulses), ``effect`` (``LubricationEffect`` and the
assembly's call), ``reference`` (exact Stokes-flow results for the tests and the benchmark).
"""

from .effect import LubricationEffect, lubrication_effects

__all__ = ["LubricationEffect", "lubrication_effects"]
