"""Domains (pipe, box) on the lattice and their no-slip walls.

Geometry. Arrays hold one node per lattice cell; node centres sit half a spacing inside the domain
edges, so a half-way bounce-back wall lies exactly on the domain boundary. Each axis that is closed
by a wall gets one layer of solid "ghost" nodes outside the domain; the pipe gets a solid ring
around its circular cross-section. z is the fastest axis in memory and (for the pipe) the axis
of the pipe, so every (x, y) column is either wholly fluid or wholly solid and the fluid kernel
sweeps only fluid columns.

Memory. The populations are ``f[q, x, y, z]`` with each q-plane contiguous (``alloc_populations``):
z rows of ``alloc_z`` slots (the kernel's z-halo), and planes ``plane_stride`` elements apart, a
few cache lines more than a plane where that keeps the q planes out of each other's cache sets.
Flat node ``n = (x * ny + y) * alloc_z + z`` (``Grid.flat``) of population ``i`` is
``plane_buffer(f)[i, n]``, the 2-D form the boundary fills and particle passes take.

Walls. Populations are never tested for walls inside the fluid sweep. Before each sweep a wall
effect writes, into the slot of the solid node that a fluid node pulls from, the population that
the wall sends back. For a link from fluid node ``x`` along ``e_i`` into solid node ``s = x + e_i``
the pull of direction ``i' = opp(i)`` at ``x`` reads slot ``(i', s)``:

* half-way bounce-back (the paper's staircase wall): ``f_i'(x, t+1) = f*_i(x, t)``;
* moving wall, Ladd's rule Eq. (8) with ``B_i = 3 rho w_i`` (lattice units):
  ``f_i'(x, t+1) = f*_i(x, t) - 2 B_i (e_i . u_w)``;
* interpolated bounce-back (Bouzidi, Firdaouss & Lallemand 2001) with ``q`` the fraction of the
  link in the fluid: ``q < 1/2``: ``2q f*_i(x) + (1-2q) f*_i(x - e_i)``;
  ``q >= 1/2``: ``f*_i(x)/(2q) + (2q-1)/(2q) f*_i'(x)``.

Slot ``(i', s)`` belongs to exactly one link (``x = s - e_i`` is unique), reads touch only fluid
nodes and writes only solid nodes, so the fills are race-free and can run in parallel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from .lattice import Lattice
from .observables import ordered_sum

SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")


@dataclass
class Grid:
    """A domain on the lattice (lattice units throughout)."""

    kind: str  # "pipe" | "box"
    lattice: Lattice
    shape: tuple[int, int, int]  # array extents in nodes, ghost layers included
    alloc_z: int  # allocated z extent (>= shape[2] + 2: z-halo of the kernel, padding against cache-set conflicts)
    periodic: tuple[bool, bool, bool]
    ghost: tuple[int, int, int]  # ghost layers on each side of each axis (0 or 1)
    solid: np.ndarray  # (nx, ny, nz) bool, static walls
    radius: float = 0.0  # pipe radius (lattice units)
    wall_side: np.ndarray | None = None  # (nx, ny, nz) int8 side index of ghost nodes, -1 elsewhere
    cols_x: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    cols_y: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    z0: int = 0
    z1: int = 0

    def __post_init__(self) -> None:
        nx, ny, nz = self.shape
        self.xm = ((np.arange(nx) - 1) % nx).astype(np.int64)
        self.xp = ((np.arange(nx) + 1) % nx).astype(np.int64)
        self.ym = ((np.arange(ny) - 1) % ny).astype(np.int64)
        self.yp = ((np.arange(ny) + 1) % ny).astype(np.int64)
        fluid_cols = ~self.solid.all(axis=2)
        cx, cy = np.nonzero(fluid_cols)
        self.cols_x = cx.astype(np.int64)
        self.cols_y = cy.astype(np.int64)
        g = self.ghost[2]
        self.z0, self.z1 = g, nz - g

    @property
    def nzw(self) -> int:
        return self.shape[2]

    @property
    def fluid(self) -> np.ndarray:
        return ~self.solid

    @property
    def n_fluid(self) -> int:
        return int(self.fluid.sum())

    def positions(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Node-centre coordinates (lattice units) along x, y, z.

        Pipe: the axis is at x = y = 0 and z runs from 0 to the length. Box: each axis runs from 0
        to its extent.
        """
        out = []
        for a in range(3):
            n = self.shape[a]
            c = np.arange(n) - self.ghost[a] + 0.5
            if self.kind == "pipe" and a < 2:
                c = c - self.radius
            out.append(c)
        return tuple(out)

    def flat(self, ix, iy, iz):
        return (np.asarray(ix) * self.shape[1] + np.asarray(iy)) * self.alloc_z + np.asarray(iz)


def _alloc_z(nz: int) -> int:
    # At least two spare slots per z-row: the fluid kernel keeps a one-node z-halo of a periodic
    # column there (slot nz, and the last slot before the next row), so that its pull along z
    # never splits a row (see kernels.py). Two more when nz is a multiple of 16 break the common
    # alignment of the rows of one plane (measured ~10 % on a 64^3 box before plane_stride
    # skewed the q-planes apart; not re-measured since).
    return nz + 4 if nz % 16 == 0 else nz + 2


#: when the q-planes of ``f`` would share cache sets, their stride is padded to this many cache
#: lines modulo 4 KiB (odd: every plane then has its own L1 and L2 sets; see ``plane_stride``)
PLANE_SKEW_LINES = 5
_LINE = 64
_PAGE = 4096


def plane_stride(plane: int, itemsize: int, q: int) -> int:
    """Elements from one q-plane of ``f`` to the next: ``plane`` (nodes per plane), padded when
    the q planes would otherwise start in fewer than q distinct L1 sets (4 KiB / 64 B lines).

    Why: the sweep streams q rows in and q rows out at the same node offset of every plane. When
    the plane size is a multiple of 4 KiB (any box whose x-y extent is a power of two, such as
    64^3, whatever ``alloc_z`` pads along z) all of them fall into the same L1 set (12 ways) and,
    at 128 KiB, the same L2 set. Measured, 64^3 box, median of 9 interleaved rounds: 51 MLUPS
    unpadded, 76 padded on 1 thread; 106 and 136 on 2. A stride of an odd number of lines modulo
    4 KiB gives every plane its own sets (modulo the L2's 128 KiB too). A plane that already
    spreads (the paper's pipe: 44 lines modulo 4 KiB) is left as it is; padding it measured the
    same within the noise."""
    per_line = _LINE // itemsize
    stride = -(-plane // per_line) * per_line
    lines = stride // per_line
    sets = _PAGE // _LINE
    if len({(i * lines) % sets for i in range(q)}) == q:
        return stride
    target = PLANE_SKEW_LINES * per_line
    return stride + (target - stride) % (_PAGE // itemsize)


def alloc_populations(q: int, grid: Grid, dtype) -> np.ndarray:
    """Zeroed ``f[q, x, y, alloc_z]``: a view of a C-contiguous ``(q, plane_stride)`` buffer
    (``plane_buffer`` returns it), so the q-planes are skewed across cache sets."""
    nx, ny, _ = grid.shape
    plane = nx * ny * grid.alloc_z
    buf = np.zeros((q, plane_stride(plane, np.dtype(dtype).itemsize, q)), dtype=dtype)
    return buf[:, :plane].reshape(q, nx, ny, grid.alloc_z)


def plane_buffer(f: np.ndarray) -> np.ndarray:
    """The C-contiguous ``(q, stride)`` array whose row ``i`` starts with plane ``i`` of ``f``:
    flat node ``n`` of population ``i`` is ``[i, n]`` (``Grid.flat``), as in ``f.reshape(q, -1)``
    of a contiguous ``f``. Numba functions take this 2-D form (unit stride known at compile time)."""
    if f.flags.c_contiguous:
        return f.reshape(f.shape[0], -1)
    b = f.base
    if (b is None or b.ndim != 2 or not b.flags.c_contiguous or b.shape[0] != f.shape[0]
            or b.strides[0] != f.strides[0] or b.ctypes.data != f.ctypes.data):
        raise ValueError("populations must come from alloc_populations (or be C-contiguous)")
    return b


def pipe_grid(lattice: Lattice, n_diameter: int, n_length: int) -> Grid:
    """Circular pipe of diameter ``n_diameter`` nodes along z, periodic in z, ring of solid ghosts."""
    r = n_diameter / 2.0
    n = n_diameter + 2
    c = np.arange(n) - 1 + 0.5 - r
    X, Y = np.meshgrid(c, c, indexing="ij")
    inside = X**2 + Y**2 < r * r
    solid = np.repeat(~inside[:, :, None], n_length, axis=2)
    return Grid("pipe", lattice, (n, n, n_length), _alloc_z(n_length), (False, False, True), (1, 1, 0), solid, r)


def box_grid(lattice: Lattice, size: tuple[int, int, int], walls: tuple[bool, bool, bool]) -> Grid:
    """Box of ``size`` nodes; axes with ``walls[a]`` are closed by a wall on both sides."""
    ghost = tuple(1 if w else 0 for w in walls)
    shape = tuple(size[a] + 2 * ghost[a] for a in range(3))
    solid = np.zeros(shape, dtype=bool)
    side = np.full(shape, -1, dtype=np.int8)
    for a in range(3):
        if not walls[a]:
            continue
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a] = 0
        hi[a] = shape[a] - 1
        solid[tuple(lo)] = True
        solid[tuple(hi)] = True
        # Corner ghosts are shared by two walls; the later axis wins, which only matters
        # for a diagonal link into an edge where both walls move.
        side[tuple(lo)] = 2 * a
        side[tuple(hi)] = 2 * a + 1
    periodic = tuple(not w for w in walls)
    return Grid("box", lattice, shape, _alloc_z(shape[2]), periodic, ghost, solid, wall_side=side)


@dataclass
class Links:
    """Boundary links between fluid nodes and solid wall nodes (flat indices into a q-plane)."""

    fluid: np.ndarray  # flat index of the fluid node x
    solid: np.ndarray  # flat index of s = x + e_i
    i: np.ndarray  # direction from fluid into solid
    opp: np.ndarray  # opp(i)
    q: np.ndarray  # fraction of the link in the fluid (1/2 for staircase walls)
    fluid2: np.ndarray  # flat index of x - e_i if fluid, else -1 (Bouzidi, q < 1/2)
    side: np.ndarray  # wall side index (box) or -1

    def __len__(self) -> int:
        return len(self.i)


def wall_links(grid: Grid) -> Links:
    """All links from fluid nodes into static wall nodes, sorted by memory address."""
    lat = grid.lattice
    nx, ny, nz = grid.shape
    fluid = grid.fluid
    fx, fy, fz = np.nonzero(fluid)
    parts = {k: [] for k in ("fluid", "solid", "i", "q", "fluid2", "side")}
    px, py, _ = grid.positions()
    for i in range(1, lat.q):  # over directions only; vectorised over nodes
        ex, ey, ez = lat.e[i]
        sx, sy, sz = (fx + ex) % nx, (fy + ey) % ny, (fz + ez) % nz
        hit = grid.solid[sx, sy, sz]
        if not hit.any():
            continue
        ax, ay, az = fx[hit], fy[hit], fz[hit]
        bx, by, bz = sx[hit], sy[hit], sz[hit]
        parts["fluid"].append(grid.flat(ax, ay, az))
        parts["solid"].append(grid.flat(bx, by, bz))
        parts["i"].append(np.full(len(ax), i))
        if grid.kind == "pipe":
            parts["q"].append(_circle_fraction(px[ax], py[ay], ex, ey, grid.radius))
        else:
            parts["q"].append(np.full(len(ax), 0.5))
        cx, cy, cz = (ax - ex) % nx, (ay - ey) % ny, (az - ez) % nz
        ok = fluid[cx, cy, cz]
        parts["fluid2"].append(np.where(ok, grid.flat(cx, cy, cz), -1))
        if grid.wall_side is not None:
            parts["side"].append(grid.wall_side[bx, by, bz].astype(np.int64))
        else:
            parts["side"].append(np.full(len(ax), -1))
    cat = {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in parts.items()}
    order = np.argsort(cat["solid"], kind="stable")
    i = cat["i"][order].astype(np.int64)
    return Links(
        fluid=cat["fluid"][order].astype(np.int64),
        solid=cat["solid"][order].astype(np.int64),
        i=i,
        opp=lat.opp[i].astype(np.int64),
        q=cat["q"][order].astype(np.float64),
        fluid2=cat["fluid2"][order].astype(np.int64),
        side=cat["side"][order].astype(np.int64),
    )


def _circle_fraction(x, y, ex, ey, r):
    """Fraction q in (0, 1] of the link from (x, y) along (ex, ey) before it leaves the circle r."""
    a = float(ex * ex + ey * ey)
    b = 2.0 * (x * ex + y * ey)
    c = x * x + y * y - r * r  # < 0: the start is inside
    return (-b + np.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


@njit(parallel=True, cache=True, fastmath=True)
def fill_bounce_back(f2, fluid, solid, i, opp):
    """Half-way bounce-back: slot (opp i, s) <- f*_i(x)."""
    for k in prange(len(i)):
        f2[opp[k], solid[k]] = f2[i[k], fluid[k]]


@njit(parallel=True, cache=True, fastmath=True)
def fill_moving_bounce_back(f2, fluid, solid, i, opp, delta):
    """Ladd's moving-wall bounce-back, Eq. (8): slot (opp i, s) <- f*_i(x) - 2 B_i (e_i . u_w).

    ``delta[k] = 2 B_i (e_i . u_w) = 6 w_i rho_0 (e_i . u_w)`` is constant for a wall of constant
    velocity and is precomputed per link.
    """
    for k in prange(len(i)):
        f2[opp[k], solid[k]] = f2[i[k], fluid[k]] - delta[k]


@njit(parallel=True, cache=True)
def fill_bouzidi(f2, fluid, solid, i, opp, q, fluid2, w_link, w_sum):
    """Interpolated bounce-back (Bouzidi et al. 2001), linear in q; second order for curved walls.

    The interpolation is not mass-conserving: in a closed (periodic) pipe the mass drifts
    steadily (measured +1.2 % per 10^4 steps at D = 8). The excess over plain bounce-back,
    ``sum_k (f_returned - f_sent)``, is therefore removed again each step, spread over the links
    in proportion to their lattice weights (a uniform density correction at the wall), which
    keeps the total mass exact to round-off and the scheme's order of accuracy.
    """
    n = len(i)
    excess = np.empty(n)
    for k in prange(n):
        qk = q[k]
        a = f2[i[k], fluid[k]]
        if qk < 0.5 and fluid2[k] >= 0:
            val = 2.0 * qk * a + (1.0 - 2.0 * qk) * f2[i[k], fluid2[k]]
        elif qk < 0.5:
            # No second fluid node behind x (a wall thinner than two nodes): fall back to the
            # q >= 1/2 form evaluated at q = 1/2, i.e. plain bounce-back.
            val = a
        else:
            val = a / (2.0 * qk) + (2.0 * qk - 1.0) / (2.0 * qk) * f2[opp[k], fluid[k]]
        f2[opp[k], solid[k]] = val
        excess[k] = val - a
    corr = ordered_sum(excess) / w_sum
    for k in prange(n):
        f2[opp[k], solid[k]] -= corr * w_link[k]
