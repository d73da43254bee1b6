"""Fused stream-and-collide kernels, generated per scene from the effects it contains.

One kernel performs, for every fluid node, the pull streaming of Eq. (1)
(``f_i(x, t+1) <- f*_i(x - e_i, t)``), the moments of Eq. (4), and the collision: BGK (Eqs. (2)-(3))
or TRT (two relaxation rates on the even/odd parts of each opposite pair). A body force enters by
Guo's second-order scheme (Guo, Zheng & Shi 2002): the velocity is shifted by ``F/(2 rho)`` and
a source ``(1 - omega/2) w_i [3 (e_i - u) + 9 (e_i . u) e_i] . F`` is added (split into even and
odd parts with their own rates for TRT).

Why generated code: a scene pays only for the physics it declares. A kernel without a body force
has no force arithmetic in it, BGK has no TRT split, and the flux reduction that the flow-rate
controller needs exists only when that controller runs. Rendering the source for exactly the
requested combination (velocity set, collision operator, forcing, flux, precision) unrolls the
loop over directions with literal weights and velocities, like lbmpy does, and leaves no branch or
mask for an absent feature in the hot loop. The rendered module is written to a cache folder and
imported, so numba's on-disk cache (``cache=True``) works across runs.

Density floor (scenes with free particles only, ``KernelSpec.floor``): after the moments, a node
below ``rho_min`` gets ``d_rho = rho_min - rho`` added as ``w_i d_rho`` to its populations, which
adds mass and no momentum (``sum_i w_i e_i = 0``); the row also sums ``d_rho`` and the number of
nodes floored, for the summary. Why: see ``effects.StreamCollide``. It is written without a branch
(``max``), so the row still vectorizes; measured cost on the paper's pipe, 1 thread: 3-8 % of the
sweep (median of per-round ratios over three runs on the shared machine: 1.08, 0.97, 1.14).

Memory layout (structure of arrays): ``f[q, x, y, z]``, z fastest, each q-plane contiguous and the
planes a few cache lines more than their size apart (``boundaries.plane_stride``: against cache-set
conflicts between the q streams); the kernel takes the ``(q, stride)`` buffer. Walls and
particle surfaces are not tested in the kernel: before each sweep the boundary effects write the
bounced-back populations into the "ghost" slots of the solid nodes that fluid nodes pull from
(see ``boundaries.py``), so the sweep itself is branch-free. Only fluid *columns* (x, y) are
swept, each over its z-range, so the solid region outside a pipe costs nothing.

Loop structure (the one lbmpy generates): for each column, one loop over z reads the q pulled
rows of ``src`` and writes the q rows of ``dst`` directly, with unit-stride vector loads and
stores and no staging copy. Three things make LLVM compile it so from numba:

* the rows are passed to the row loop as separate ``noalias`` arguments (``_pipeline``), so
  LLVM knows the written rows overlap nothing else and vectorizes without run-time checks;
* a periodic z-axis does not split the row: the pulls at z = 0 and z = nz - 1 read one slot
  before / after the row, in the row padding of ``Grid.alloc_z`` (at least two spare slots),
  filled with the wrapped-around value just before the row is swept (a z-halo of one node,
  2 x 5 scalar copies per column for D3Q15); without that room the two end nodes are swept one
  by one;
* offsets and counters are unsigned, so numba emits no negative-index wrap-around test.

``benchmarks/fluid.py`` measures the sweep against the copy-bandwidth roofline and lbmpy's kernel
(figures: benchmarks/README.md); the q-planes are skewed across cache sets
(``boundaries.plane_stride``) so that the 2q streams of a row do not evict each other.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
from numba.core import lowering
from numba.core.compiler import CompilerBase, DefaultPassBuilder
from numba.core.compiler_machinery import register_pass
from numba.core.typed_passes import NativeLowering

from .. import cache_root
from .collision import CollisionOperator
from .lattice import Lattice, get_lattice

GENERATOR_VERSION = "7"


@dataclass(frozen=True)
class KernelSpec:
    """What one generated kernel does. Each field is an effect the scene asked for."""

    lattice: str = "D3Q15"
    collision: CollisionOperator = CollisionOperator.BGK  # a name ("bgk") is converted
    forcing: bool = False  # Guo body force
    flux: bool = False  # return the total z-momentum (for the flow-rate controller)
    precision: str = "float64"  # "float64" | "float32"
    floor: bool = False  # density floor for under-resolved films (scenes with free particles)

    def __post_init__(self):
        try:
            op = CollisionOperator(self.collision)
        except ValueError:
            choices = " or ".join(m.value for m in CollisionOperator)
            raise ValueError(f"unknown collision operator {self.collision!r}: choose {choices}") from None
        object.__setattr__(self, "collision", op)  # frozen: set once, here

    def describe(self) -> str:
        parts = [f"stream+collide {self.lattice} {self.collision.upper()}"]
        if self.forcing:
            parts.append("Guo body force")
        if self.flux:
            parts.append("flux sum")
        if self.floor:
            parts.append("density floor")
        parts.append(self.precision)
        return ", ".join(parts)


def _lit(x: float, precision: str) -> str:
    s = repr(float(x))
    return f"np.float32({s})" if precision == "float32" else s


def _weighted_sum(coeffs, names) -> str:
    terms = []
    for c, n in zip(coeffs, names):
        if c == 1:
            terms.append(f"+ {n}")
        elif c == -1:
            terms.append(f"- {n}")
        elif c != 0:
            terms.append(f"+ {c} * {n}")
    if not terms:
        return "0.0"
    s = " ".join(terms)
    return s[2:] if s.startswith("+ ") else "-" + s[2:]


def _wname(w: float) -> str:
    fr = Fraction(w).limit_denominator(10000)
    return f"{fr.numerator}_{fr.denominator}"


def _body(lat: Lattice, spec: KernelSpec, indent: str, inp, out) -> str:
    """Source of the collision of one node: ``inp(i)`` is the expression of the streamed
    population ``i``, ``out(i)`` the target of its post-collision value."""
    P = spec.precision

    def L(x):
        return _lit(x, P)

    Q = lat.q
    e = lat.e
    lines = []
    for i in range(Q):
        lines.append(f"f{i} = {inp(i)}")
    names = [f"f{i}" for i in range(Q)]
    lines.append("rho = " + " + ".join(names))
    if spec.floor:
        # Density floor: a node below rho_min gets d_rho = rho_min - rho added as w_i d_rho to
        # each population before the collision (mass only: sum_i w_i e_i = 0). Branch-free, so
        # the row still vectorizes. The collision conserves mass, so the added w_i d_rho comes
        # out relaxed as (1 - omega) w_i d_rho on top of the collision of the unfloored values.
        lines.append(f"d_rho = max(rho_min - rho, {L(0.0)})")
        lines.append("rho = rho + d_rho")
        for wv in sorted(set(lat.w.tolist())):
            lines.append(f"g_{_wname(wv)} = {L(wv)} * cg_p * d_rho")
    for a, comp in enumerate("xyz"):
        lines.append(f"j{comp} = " + _weighted_sum(e[:, a], names))
    lines.append(f"inv_rho = {L(1.0)} / rho")
    if spec.forcing:
        for comp in "xyz":
            lines.append(f"u{comp} = (j{comp} + {L(0.5)} * F{comp}) * inv_rho")
    else:
        for comp in "xyz":
            lines.append(f"u{comp} = j{comp} * inv_rho")
    lines.append(f"usq = {L(1.5)} * (ux * ux + uy * uy + uz * uz)")
    if spec.forcing:
        lines.append("uF = ux * Fx + uy * Fy + uz * Fz")

    def edot(i, v):  # e_i . v as source text
        return _weighted_sum(e[i], [f"{v}x", f"{v}y", f"{v}z"])

    w = lat.w

    def g(i):  # the floor's relaxed mass on population i
        return f" + g_{_wname(w[i])}" if spec.floor else ""

    trt = spec.collision is CollisionOperator.TRT
    # Rest population: even only.
    lines.append(f"feq = {L(w[0])} * rho * ({L(1.0)} - usq)")
    if spec.forcing:
        lines.append(f"{out(0)} = f0 - om_p * (f0 - feq) - {L(3 * w[0])} * cf_p * uF{g(0)}")
    else:
        lines.append(f"{out(0)} = f0 - om_p * (f0 - feq){g(0)}")
    done = {0}
    for i in range(1, Q):
        if i in done:
            continue
        j = int(lat.opp[i])
        done.update((i, j))
        wi = w[i]
        lines.append(f"eu = {edot(i, 'u')}")
        # even and odd parts of the equilibrium (Eq. (3)) of the pair (i, opp i)
        lines.append(f"fep = {L(wi)} * rho * ({L(1.0)} + {L(4.5)} * eu * eu - usq)")
        lines.append(f"fem = {L(3 * wi)} * rho * eu")
        if spec.forcing:
            lines.append(f"eF = {edot(i, 'F')}")
            lines.append(f"sp = {L(wi)} * ({L(9.0)} * eu * eF - {L(3.0)} * uF)")
            lines.append(f"sm = {L(3 * wi)} * eF")
        if trt:
            lines.append(f"fp = {L(0.5)} * (f{i} + f{j})")
            lines.append(f"fm = {L(0.5)} * (f{i} - f{j})")
            lines.append("cp = om_p * (fp - fep)")
            lines.append("cm = om_m * (fm - fem)")
            if spec.forcing:
                lines.append("cp -= cf_p * sp")
                lines.append("cm -= cf_m * sm")
            lines.append(f"{out(i)} = f{i} - cp - cm{g(i)}")
            lines.append(f"{out(j)} = f{j} - cp + cm{g(j)}")
        elif spec.forcing:
            lines.append(f"{out(i)} = f{i} - om_p * (f{i} - fep - fem) + cf_p * (sp + sm){g(i)}")
            lines.append(f"{out(j)} = f{j} - om_p * (f{j} - fep + fem) + cf_p * (sp - sm){g(j)}")
        else:
            lines.append(f"{out(i)} = f{i} - om_p * (f{i} - fep - fem){g(i)}")
            lines.append(f"{out(j)} = f{j} - om_p * (f{j} - fep + fem){g(j)}")
    return "\n".join(indent + ln for ln in lines)


def _pipeline(name: str, attrs: tuple[str, ...]):
    """A numba nopython pipeline that marks every array argument ``noalias`` for LLVM and adds
    the LLVM function attributes ``attrs``.

    Why ``noalias``: the row sweep reads q rows of ``src`` and writes q rows of ``dst``. As slices
    of two arrays with run-time strides, LLVM cannot tell that the q written rows overlap neither
    each other nor the rows read, and the loop vectorizer gives up (it would need hundreds of
    run-time overlap checks). Passed as separate ``noalias`` arguments (``src`` whole, and one
    ``dst`` q-plane each) they are known to be disjoint, and the loop over z vectorizes into plain
    unit-stride vector loads and stores: the loop structure of lbmpy's generated C. The promise
    holds: the ``dst`` planes are written each through its own argument, and ``src`` is written
    only in its padding slots (the z-halo), which no other argument reaches.
    """

    class _Lower(lowering.Lower):
        def post_lower(self):
            super().post_lower()
            # llvmlite's attribute set accepts only keyword attributes; LLVM's string attributes
            # go into the IR verbatim.
            for attr in attrs:
                set.add(self.builder.function.attributes, attr)

    @register_pass(mutates_CFG=True, analysis_only=False)
    class _Lowering(NativeLowering):
        _name = f"lbmpipe_{name}_lowering"

        @property
        def lowering_class(self):
            return _Lower

    class Pipeline(CompilerBase):
        def define_pipelines(self):
            self.state.flags.noalias = True
            pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
            pm.passes = [(_Lowering if cls is NativeLowering else cls, desc) for cls, desc in pm.passes]
            return [pm]

    Pipeline.__name__ = Pipeline.__qualname__ = f"{name.capitalize()}Pipeline"
    return Pipeline


# LLVM function attributes of the row loop. On AVX-512 CPUs LLVM prefers 256-bit vectors by
# default (against clock throttling in compute-bound code); this loop is bound by memory
# traffic, and 512-bit vectors (the width of lbmpy's generated code) measured ~10 % faster on
# the 64^3 box. The attribute is a preference only: CPUs without AVX-512 keep their widest
# vectors. numba vectorizes each function before linking it into its callers, so the row loop
# carries the attribute itself and is then inlined into the column sweep (which carries it too,
# and is kept out of the parallel loop's function so that it keeps it).
_WIDE = ('"prefer-vector-width"="512"', '"min-legal-vector-width"="512"')
RowPipeline = _pipeline("row", _WIDE + ("alwaysinline",))
SweepPipeline = _pipeline("sweep", _WIDE + ("noinline",))


_XS = {1: "ixm", -1: "ixp", 0: "ix"}  # pull: population i at x comes from x - e_i
_YS = {1: "iym", -1: "iyp", 0: "iy"}


def render(spec: KernelSpec) -> str:
    """Python source of the kernel module for ``spec``."""
    lat = get_lattice(spec.lattice)
    Q = lat.q
    if np.any(lat.e[0] != 0):
        raise ValueError("the kernel expects the rest population first")  # halo slot of plane 0 at index -1
    P = spec.precision
    cast = (lambda v: f"np.float32({v})") if P == "float32" else (lambda v: f"float({v})")
    trt = spec.collision is CollisionOperator.TRT
    # run-time parameters of the collision, handed to the row sweep
    params = ["om_p"] + (["om_m"] if trt else [])
    setup = [f"om_p = {cast('omega')}"] + ([f"om_m = {cast('omega_m')}"] if trt else [])
    if spec.forcing:
        for name, v in (("Fx", "fx"), ("Fy", "fy"), ("Fz", "fz"), ("cf_p", "1.0 - 0.5 * omega"),
                        ("cf_m", "1.0 - 0.5 * omega_m")):
            if name == "cf_m" and not trt:
                continue
            setup.append(f"{name} = {cast(v)}")
            params.append(name)
    if spec.floor:
        setup += [f"rho_min = {cast('rho_min')}", f"cg_p = {cast('1.0 - omega')}"]
        params += ["rho_min", "cg_p"]
    par = ", ".join(params)
    s_args = "s"
    d_args = ", ".join(f"d{i}" for i in range(Q))
    o_args = ", ".join(f"o{i}" for i in range(Q))
    body = _body(lat, spec, " " * 8, lambda i: f"s[o{i} + k]", lambda i: f"d{i}[od + k]")
    if spec.flux:
        # z-momentum of the streamed populations summed over the row: the flux the flow-rate
        # controller needs (Guo's half-force shift is added per node by the caller).
        row_head = "    jz_block_flux = 0.0\n"
        body += "\n" + " " * 8 + "jz_block_flux += jz"
        ret = "jz_block_flux"
    else:
        row_head = ""
        ret = "0.0"
    if spec.floor:
        # the floor's tally over the row: mass added and node updates floored
        row_head += "    floor_mass = 0.0\n    floor_nodes = 0.0\n"
        body += "\n" + " " * 8 + "floor_mass += d_rho"
        body += "\n" + " " * 8 + "floor_nodes += 1.0 if d_rho > 0.0 else 0.0"
        row_tail = f"    return {ret}, floor_mass, floor_nodes\n"
    else:
        row_tail = f"    return {ret}\n"
    # plane i of src / dst as a 1-d array: argument s_i / d_i of the row sweep
    planes = "    s = src.reshape(-1)\n    plane = src.shape[1]\n" + "\n".join(f"    d{i} = dst[{i}]" for i in range(Q))
    rows = sorted({(int(ex), int(ey)) for ex, ey in lat.e[:, :2]})
    row_src = "\n".join(" " * 8 + f"r_{_XS[ex]}_{_YS[ey]} = ({_XS[ex]} * ny + {_YS[ey]}) * nza" for ex, ey in rows)

    def halo_fill(ez: int) -> str:
        # plane i's source row of this column: slot -1 <- z = nzw - 1 (ez = +1); slot nzw <- z = 0
        out = []
        for i in range(Q):
            ex, ey = int(lat.e[i, 0]), int(lat.e[i, 1])
            if int(lat.e[i, 2]) != ez:
                continue
            r = f"{i} * plane + r_{_XS[ex]}_{_YS[ey]}"
            out.append(f"s[{r} - 1] = s[{r} + nzw - 1]" if ez == 1 else f"s[{r} + nzw] = s[{r}]")
        return "\n".join(" " * 12 + ln for ln in out) or " " * 12 + "pass"

    def offsets(z: str, wrap: bool) -> str:
        out = []
        for i in range(Q):
            ex, ey, ez = (int(c) for c in lat.e[i])
            zz = f"{z} - {ez}" if ez > 0 else (f"{z} + {-ez}" if ez < 0 else z)
            if wrap and ez:
                zz = f"({zz} + nzw) % nzw"
            out.append(f"np.uint64({i} * plane + r_{_XS[ex]}_{_YS[ey]} + {zz})" if i else f"np.uint64(r_{_XS[ex]}_{_YS[ey]} + {zz})")
        return ", ".join(out)

    def call(z: str, count: str, wrap: bool) -> str:
        fn = "_end" if wrap else "_row"
        return (f"{fn}(s, {d_args},\n{' ' * 17}{offsets(z, wrap)},\n{' ' * 17}"
                f"np.uint64(r_ix_iy + {z}), np.uint64({count}), {par})")

    half_force = " + 0.5 * fz * (c_hi - c_lo) * (z1 - z0)" if spec.flux else ""
    if spec.floor:
        acc = "r = "
        tally = "\n" + " " * 12 + "acc += r[0]\n" + " " * 12 + "fm += r[1]\n" + " " * 12 + "fn += r[2]"
        sweep_head = "acc = 0.0\n    fm = 0.0\n    fn = 0.0"
        sweep_ret = "acc, fm, fn"
        collect = ("res = _sweep", "partial[chunk, 0] = res[0]{half_force}\n        partial[chunk, 1] = res[1]\n"
                   "        partial[chunk, 2] = res[2]")
        finish = ("total = 0.0\n    for chunk in range(nchunks):\n        total += partial[chunk, 0]\n"
                  "        tally[0] += partial[chunk, 1]\n        tally[1] += partial[chunk, 2]\n    return total")
        part_shape = "(nchunks, 3)"
        collect_tail = "\n        " + collect[1].format(half_force=half_force)
    else:
        acc = "acc += " if spec.flux else ""
        tally = ""
        sweep_head = "acc = 0.0"
        sweep_ret = "acc"
        collect = ("partial[chunk] = _sweep", "")
        finish = "total = 0.0\n    for chunk in range(nchunks):\n        total += partial[chunk]\n    return total"
        part_shape = "nchunks"
        collect_tail = ""
    halo_lo, halo_hi = halo_fill(1), halo_fill(-1)
    nl4 = "\n    "
    return f"""# Generated by lbmpipe.fluid.kernels (version {GENERATOR_VERSION}); do not edit.
# {spec.describe()}
import numpy as np
from numba import njit, prange

from {__name__} import RowPipeline, SweepPipeline


@njit(pipeline_class=RowPipeline, fastmath=True, cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _row(s, {d_args},
         {o_args}, od, n, {par}):
    # Unsigned offsets and counter: no negative-index wrap-around, so LLVM sees unit-stride rows.
{row_head}    for k in range(n):
{body}
{row_tail}

# The same update for the end nodes of a periodic column when the rows have no room for the
# z-halo: not inlined and left scalar, so the vectorizer compiles only one copy of the body.
@njit(fastmath=True, cache=True, nogil=True, error_model="numpy", boundscheck=False)
def _end(s, {d_args},
         {o_args}, od, n, {par}):
{row_head}    for k in range(n):
{body}
{row_tail}

@njit(pipeline_class=SweepPipeline, fastmath=True, cache=True, nogil=True, error_model="numpy",
      boundscheck=False)
def _sweep(s, {d_args},
           cols_x, cols_y, xm, xp, ym, yp, c_lo, c_hi, plane, ny, nza, nzw, z0, z1, lo, n,
           halo_lo, halo_hi, end_lo, end_hi, {par}):
    # Columns c_lo..c_hi-1: one row of every q-plane each.
    {sweep_head}
    for c in range(c_lo, c_hi):
        ix = cols_x[c]
        iy = cols_y[c]
        ixm = xm[ix]
        ixp = xp[ix]
        iym = ym[iy]
        iyp = yp[iy]
{row_src}
        if halo_lo:
{halo_lo}
        if halo_hi:
{halo_hi}
        if n > 0:
            {acc}{call("lo", "n", False)}{tally}
        if end_lo:
            {acc}{call("z0", "1", True)}{tally}
        if end_hi:
            {acc}{call("(z1 - 1)", "1", True)}{tally}
    return {sweep_ret}


@njit(parallel=True, fastmath=True, cache=True, nogil=True, error_model="numpy", boundscheck=False)
def stream_collide(src, dst, ny, nza, cols_x, cols_y, xm, xp, ym, yp, z0, z1, nzw, omega, omega_m, fx, fy, fz,
                   nchunks, rho_min, tally):
    {nl4.join(setup)}
{planes}
    # Periodic z: the pull at z = 0 (z = nzw - 1) reads z = -1 (z = nzw). With two spare slots
    # at the end of each row (Grid.alloc_z), these are the slot just before the row (the last
    # padding slot of the previous row) and the first padding slot after it, filled with the
    # wrapped-around value just before the row is swept; then every row is one unit-stride loop
    # over its whole z-range. Without the room, the end nodes are swept one by one.
    wrap_lo = z0 == 0
    wrap_hi = z1 == nzw
    halo = nza >= nzw + 2
    if halo or not (wrap_lo or wrap_hi):
        lo = z0
        hi = z1
        end_lo = False
        end_hi = False
    else:
        lo = max(z0, 1)
        hi = min(z1, nzw - 1)
        end_lo = z0 < lo
        end_hi = z1 > hi and z1 - 1 >= lo
    n = max(hi - lo, 0)
    halo_lo = halo and wrap_lo
    halo_hi = halo and wrap_hi
    partial = np.zeros({part_shape})
    ncol = cols_x.shape[0]
    for chunk in prange(nchunks):
        c_lo = chunk * ncol // nchunks
        c_hi = (chunk + 1) * ncol // nchunks
        {collect[0]}(s, {d_args},
                                cols_x, cols_y, xm, xp, ym, yp, c_lo, c_hi, plane, ny, nza, nzw, z0, z1, lo, n,
                                halo_lo, halo_hi, end_lo, end_hi, {par}){"" if spec.floor else half_force}{collect_tail}
    # summed in chunk order, not by numba's parallel reduction: the same bits on any thread count
    {finish}
"""


def cache_dir() -> Path:
    root = os.environ.get("LBMPIPE_CACHE_DIR")
    if root:
        return Path(root)
    return cache_root() / "kernels"


_LOADED: dict[KernelSpec, object] = {}


def get_kernel(spec: KernelSpec):
    """The compiled ``stream_collide`` function for ``spec`` (generated and cached on first use).

    Signature: ``stream_collide(src, dst, ny, nza, cols_x, cols_y, xm, xp, ym, yp, z0, z1, nzw,
    omega, omega_m, fx, fy, fz, nchunks, rho_min, tally) -> jz_sum``. ``src`` and ``dst`` are the
    ``(q, plane stride)`` buffers of ``boundaries.plane_buffer`` (node ``(x, y, z)`` of plane ``i``
    at ``[i, (x * ny + y) * nza + z]``); ``src`` holds post-collision populations at time t (with
    boundary ghost slots filled), ``dst`` receives those of t+1. ``omega_m`` is the odd-moment rate
    of TRT (ignored by BGK), ``f*`` the force density (ignored without forcing). ``jz_sum`` is the
    sum of ``rho u_z`` over the swept nodes when ``spec.flux`` (else 0). The kernel also writes
    the z-halo of periodic columns into the row padding of ``src`` (slots z >= nz, never read
    as nodes).
    """
    if spec in _LOADED:
        return _LOADED[spec]
    if spec.precision not in ("float64", "float32"):
        raise ValueError(f"unknown precision {spec.precision!r}: choose float64 or float32")
    src = render(spec)
    digest = hashlib.sha1(src.encode()).hexdigest()[:16]
    folder = cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    name = f"lbmpipe_kernel_{digest}"
    path = folder / f"{name}.py"
    if not path.exists() or path.read_text() != src:
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(src)
        os.replace(tmp, path)  # atomic: parallel snakemake jobs may render the same kernel
    module_spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module
    module_spec.loader.exec_module(module)
    _LOADED[spec] = module.stream_collide
    return module.stream_collide


def dtype_of(precision: str):
    return np.float32 if precision == "float32" else np.float64
