"""The collision model's parameters and the geometry that bounds the particles: what a scene
check needs (``lbmpipe.inputs``, ``lbmpipe.scene``) without importing the collision kernels
(``lbmpipe.particles.collisions``, which re-exports these names)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

PIPE = 0
BOX = 1

#: Overlaps at any time stay within this many ``overlap_tol`` (``collisions.step``: the overlap bound
#: and its sources); the run-time guard stops a run beyond it (``lbmpipe.guard``).
OVERLAP_BOUND_FACTOR = 10.0


@dataclass(frozen=True)
class Domain:
    """Geometry that bounds the particles.

    ``kind = "pipe"``: a circular pipe of ``radius`` about the axis through ``center`` (x, y),
    parallel to z, periodic along z with period ``length`` (z in ``[z0, z0 + length)``).
    ``kind = "box"``: planar walls at ``lo`` and ``hi`` (per axis x, y, z); an axis with
    ``periodic[a]`` has no walls but is periodic with period ``hi[a] - lo[a]``.
    Use the constructors ``Domain.pipe(...)`` and ``Domain.box(...)``.
    """

    kind: str
    radius: float = 0.0
    length: float = 0.0
    center: tuple = (0.0, 0.0)
    z0: float = 0.0
    lo: tuple = (0.0, 0.0, 0.0)
    hi: tuple = (0.0, 0.0, 0.0)
    periodic: tuple = (False, False, False)

    @classmethod
    def pipe(cls, radius: float, length: float, center=(0.0, 0.0), z0: float = 0.0) -> "Domain":
        if not (radius > 0.0 and length > 0.0):
            raise ValueError(f"Domain.pipe: radius and length must be > 0, got {radius}, {length}")
        cx, cy = float(center[0]), float(center[1])
        return cls(
            kind="pipe", radius=float(radius), length=float(length), center=(cx, cy), z0=float(z0),
            lo=(cx - radius, cy - radius, float(z0)), hi=(cx + radius, cy + radius, float(z0) + length),
            periodic=(False, False, True),
        )

    @classmethod
    def box(cls, lo, hi, periodic=(False, False, False)) -> "Domain":
        lo = tuple(float(a) for a in lo)
        hi = tuple(float(a) for a in hi)
        periodic = tuple(bool(p) for p in periodic)
        if len(lo) != 3 or len(hi) != 3 or len(periodic) != 3 or any(h <= l for l, h in zip(lo, hi)):
            raise ValueError(f"Domain.box: need 3 axes with hi > lo, got lo={lo}, hi={hi}, periodic={periodic}")
        return cls(kind="box", lo=lo, hi=hi, periodic=periodic)

    def arrays(self):
        """(code, radius, cx, cy, lo (3,), hi (3,), periodic (3,) bool) for the kernels, made once
        per domain (the kernels only read them): the collision step asks for them every time step."""
        return self._arrays

    @cached_property
    def _arrays(self):
        if self.kind not in ("pipe", "box"):
            raise ValueError(f"Domain.kind must be 'pipe' or 'box', got {self.kind!r}")
        return (
            PIPE if self.kind == "pipe" else BOX,
            float(self.radius), float(self.center[0]), float(self.center[1]),
            np.array(self.lo, dtype=np.float64), np.array(self.hi, dtype=np.float64),
            np.array(self.periodic, dtype=np.bool_),
        )


@dataclass(frozen=True)
class CollisionParams:
    """Parameters of the collision model (lengths in the units of the positions, lattice units in
    the solver; ``dt`` is passed to ``resolve_collisions``).

    - ``restitution``: ``k`` of Eq. (17); 1 = elastic (the paper's setting).
    - ``contact_gap``: a signed gap at or below this counts as contact (the fluid cannot resolve
      gaps below a lattice spacing, so the bounce happens at this sub-grid separation).
    - ``speculative``: also treat as contacts the pairs that would overlap after a free step of
      ``dt`` at the current velocities (``collisions.toi``).
    - ``overlap_tol``: largest overlap left after the call; ``overlap_bound`` (``OVERLAP_BOUND_FACTOR``
      times it) bounds the overlaps at any time (``collisions.step``).
    - ``manifold_tol``: flatness tolerance of the contact-patch centroid (``lbmpipe.particles.contact``).
    - ``skin``: extra broad-phase margin; also the displacement budget of the projection before
      the pair list is rebuilt.
    - ``max_sweeps``, ``max_projection_iters``: caps of the Gauss-Seidel loops.
    - ``translation_iters``: sweeps of the translation-only projection after which a configuration
      it has not freed counts as jammed and the rotating projection takes over. Unjammed steps
      need few (at most 8 in 400 steps of each dense paper case but one); in the jams of 16 mm
      cylinders at 50 % the translations pushed bodies back and forth for 97-206 sweeps (shifts
      adding up to 1.6-4.6 lattice spacings for a net 0.02-0.05) where the rotating projection,
      started after 10-20, was done in about 6: 9-11 ms against 1.2-2.7 ms a step.
    - ``list_skin``: extra margin of the Verlet list kept over calls (``NeighbourList``): it is
      rebuilt once a body has moved by half of it. Only the cost depends on it, not the result.
    - ``rest_speed``: approach speeds at or below it are loads, taken up with ``k = 0``
      (``collisions.impulse``: impacts and loads).
    """

    restitution: float = 1.0
    contact_gap: float = 0.1
    speculative: bool = True
    overlap_tol: float = 0.01
    manifold_tol: float = 0.1
    skin: float = 0.5
    max_sweeps: int = 100
    max_projection_iters: int = 200
    translation_iters: int = 20
    list_skin: float = 1.0
    rest_speed: float = 0.0

    def __post_init__(self):
        if not (0.0 <= self.restitution <= 1.0):
            raise ValueError(f"CollisionParams.restitution must be in [0, 1], got {self.restitution}")
        if self.contact_gap < 0.0 or self.overlap_tol <= 0.0 or self.manifold_tol < 0.0 or self.skin <= 0.0:
            raise ValueError(f"CollisionParams: contact_gap >= 0, overlap_tol > 0, manifold_tol >= 0, skin > 0 ({self})")
        if self.translation_iters < 1 or self.max_projection_iters < 1:
            raise ValueError(f"CollisionParams: translation_iters >= 1, max_projection_iters >= 1 ({self})")
        if not self.list_skin >= 0.0:
            raise ValueError(f"CollisionParams.list_skin must be >= 0, got {self.list_skin}")
        if not self.rest_speed >= 0.0:
            raise ValueError(f"CollisionParams.rest_speed must be >= 0, got {self.rest_speed}")

    @property
    def overlap_bound(self) -> float:
        """Largest overlap at any time, before or after a call (``collisions.step``)."""
        return OVERLAP_BOUND_FACTOR * self.overlap_tol


def min_periodic_length(rb_max, contact_gap, skin):
    """Shortest periodic length in which the pair search over bodies of bounding radius up to
    ``rb_max`` meets no pair twice: two interaction ranges ``2 (2 rb_max + contact_gap + skin)``
    (lattice units). The one rule both the run (``collisions.step._periodic_status``) and ``lbmpipe check``
    (``lbmpipe.inputs.pair_rule_errors``) apply."""
    return 2.0 * (2.0 * rb_max + contact_gap + skin)
