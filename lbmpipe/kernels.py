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

Memory layout (structure of arrays): ``f[q, x, y, z]``, C-contiguous, z fastest. Walls and
particle surfaces are not tested in the kernel: before each sweep the boundary effects write the
bounced-back populations into the "ghost" slots of the solid nodes that fluid nodes pull from
(see ``boundaries.py``), so the sweep itself is branch-free. Only fluid *columns* (x, y) are
swept, each over its z-range, so the solid region outside a pipe costs nothing.
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

from .lattice import Lattice, get_lattice

GENERATOR_VERSION = "4"


@dataclass(frozen=True)
class KernelSpec:
    """What one generated kernel does. Each field is an effect the scene asked for."""

    lattice: str = "D3Q15"
    collision: str = "bgk"  # "bgk" | "trt"
    forcing: bool = False  # Guo body force
    flux: bool = False  # return the total z-momentum (for the flow-rate controller)
    precision: str = "float64"  # "float64" | "float32"

    def describe(self) -> str:
        parts = [f"stream+collide {self.lattice} {self.collision.upper()}"]
        if self.forcing:
            parts.append("Guo body force")
        if self.flux:
            parts.append("flux sum")
        parts.append(self.precision)
        return ", ".join(parts)


def _lit(x: float, precision: str) -> str:
    s = repr(float(x))
    return f"np.float32({s})" if precision == "float32" else s


def _frac(w: float) -> str:
    fr = Fraction(w).limit_denominator(10000)
    return f"({fr.numerator}.0/{fr.denominator}.0)"


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


def _body(lat: Lattice, spec: KernelSpec, indent: str, blk: int) -> str:
    """Source of the per-node collision on the staging buffer ``W`` at offset ``k``.

    Inputs (streamed populations) are ``W[i*blk + k]``, outputs go to ``W[(q+i)*blk + k]``:
    literal offsets into one buffer let LLVM prove the loop free of aliasing and vectorize it.
    """
    P = spec.precision

    def L(x):
        return _lit(x, P)

    Q = lat.q
    e = lat.e
    lines = []
    for i in range(Q):
        lines.append(f"f{i} = W[{i * blk} + k]")
    names = [f"f{i}" for i in range(Q)]
    lines.append("rho = " + " + ".join(names))
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

    def out(i):
        return f"W[{(Q + i) * blk} + k]"

    w = lat.w
    trt = spec.collision == "trt"
    # Rest population: even only.
    lines.append(f"feq = {L(w[0])} * rho * ({L(1.0)} - usq)")
    if spec.forcing:
        lines.append(f"{out(0)} = f0 - om_p * (f0 - feq) - {L(3 * w[0])} * cf_p * uF")
    else:
        lines.append(f"{out(0)} = f0 - om_p * (f0 - feq)")
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
            lines.append(f"{out(i)} = f{i} - cp - cm")
            lines.append(f"{out(j)} = f{j} - cp + cm")
        elif spec.forcing:
            lines.append(f"{out(i)} = f{i} - om_p * (f{i} - fep - fem) + cf_p * (sp + sm)")
            lines.append(f"{out(j)} = f{j} - om_p * (f{j} - fep + fem) + cf_p * (sp - sm)")
        else:
            lines.append(f"{out(i)} = f{i} - om_p * (f{i} - fep - fem)")
            lines.append(f"{out(j)} = f{j} - om_p * (f{j} - fep + fem)")
    return "\n".join(indent + ln for ln in lines)


BLOCK = 64  # z-nodes staged at a time: 2 x Q x 64 x 8 B = 15 KiB for D3Q15, fits in L1


def _gather(lat: Lattice, indent: str, blk: int) -> str:
    """Copy the streamed rows into the staging buffer (pull: row i comes from x - e_i)."""
    xs = {1: "ixm", -1: "ixp", 0: "ix"}
    ys = {1: "iym", -1: "iyp", 0: "iy"}
    lines = []
    for i in range(lat.q):
        X, Y, ez = xs[lat.e[i, 0]], ys[lat.e[i, 1]], int(lat.e[i, 2])
        o = i * blk
        row = f"src[{i}, {X}, {Y}]"
        if ez == 0:
            lines.append(f"W[{o}:{o} + n] = {row}[za:zb]")
        elif ez == 1:  # pulls from z - 1: wraps at the low end of a periodic column
            lines += [
                "if za >= 1:",
                f"    W[{o}:{o} + n] = {row}[za - 1:zb - 1]",
                "else:",
                f"    W[{o}] = {row}[nzw - 1]",
                f"    W[{o} + 1:{o} + n] = {row}[0:zb - 1]",
            ]
        else:  # pulls from z + 1: wraps at the high end
            lines += [
                "if zb < nzw:",
                f"    W[{o}:{o} + n] = {row}[za + 1:zb + 1]",
                "else:",
                f"    W[{o}:{o} + n - 1] = {row}[za + 1:zb]",
                f"    W[{o} + n - 1] = {row}[0]",
            ]
    return "\n".join(indent + ln for ln in lines)


def _scatter(lat: Lattice, indent: str, blk: int) -> str:
    return "\n".join(
        f"{indent}dst[{i}, ix, iy, za:zb] = W[{(lat.q + i) * blk}:{(lat.q + i) * blk} + n]" for i in range(lat.q)
    )


def render(spec: KernelSpec) -> str:
    """Python source of the kernel module for ``spec``."""
    lat = get_lattice(spec.lattice)
    P = spec.precision
    blk = BLOCK
    cast = (lambda v: f"np.float32({v})") if P == "float32" else (lambda v: f"float({v})")
    force_setup = ""
    if spec.forcing:
        force_setup = "".join(
            f"    {name} = {cast(v)}\n"
            for name, v in (("Fx", "fx"), ("Fy", "fy"), ("Fz", "fz"), ("cf_p", "1.0 - 0.5 * omega"),
                            ("cf_m", "1.0 - 0.5 * omega_m"))
        )
    # The flux is summed per chunk by a separate function over the staged (streamed) populations:
    # numba's parfor reduction analysis rejects a scalar reduction inside the vectorised loop.
    flux_fn = ""
    flux_call = ""
    if spec.flux:
        terms = " ".join(f"{'+' if lat.e[i, 2] > 0 else '-'} W[{i * blk} + k]" for i in range(lat.q) if lat.e[i, 2])
        flux_fn = f"""

@njit(cache=True, fastmath=True, inline="never")
def _block_flux(W, n, fz):
    s = 0.0
    for k in range(n):
        s += {terms.lstrip('+ ')}
    return s + 0.5 * n * fz
"""
        flux_call = " " * 16 + "partial[chunk] += _block_flux(W, n, Fz)\n"
    return f'''# Generated by lbmpipe.kernels (version {GENERATOR_VERSION}); do not edit.
# {spec.describe()}
import numpy as np
from numba import njit, prange


@njit(parallel=True, fastmath=True, cache=True, nogil=True, error_model="numpy", boundscheck=False)
def stream_collide(src, dst, cols_x, cols_y, xm, xp, ym, yp, z0, z1, nzw, omega, omega_m, fx, fy, fz, nchunks):
    om_p = {cast('omega')}
    om_m = {cast('omega_m')}
{force_setup}    partial = np.zeros(nchunks)
    ncol = cols_x.shape[0]
    for chunk in prange(nchunks):
        # One staging buffer per chunk of columns, not per column: allocation is not free.
        W = np.empty({2 * lat.q * blk}, dtype=src.dtype)
        c_lo = chunk * ncol // nchunks
        c_hi = (chunk + 1) * ncol // nchunks
        for c in range(c_lo, c_hi):
            ix = cols_x[c]
            iy = cols_y[c]
            ixm = xm[ix]
            ixp = xp[ix]
            iym = ym[iy]
            iyp = yp[iy]
            for za in range(z0, z1, {blk}):
                zb = min(za + {blk}, z1)
                n = zb - za
{_gather(lat, " " * 16, blk)}
                for k in range(n):
{_body(lat, spec, " " * 20, blk)}
{_scatter(lat, " " * 16, blk)}
{flux_call}    return partial.sum()
{flux_fn}'''


def cache_dir() -> Path:
    root = os.environ.get("LBMPIPE_CACHE_DIR")
    if root:
        return Path(root)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lbmpipe" / "kernels"


_LOADED: dict[KernelSpec, object] = {}


def get_kernel(spec: KernelSpec):
    """The compiled ``stream_collide`` function for ``spec`` (generated and cached on first use).

    Signature: ``stream_collide(src, dst, cols_x, cols_y, xm, xp, ym, yp, z0, z1, nzw, omega,
    omega_m, fx, fy, fz) -> jz_sum``. ``src`` holds post-collision populations at time t (with
    boundary ghost slots filled), ``dst`` receives those of t+1. ``omega_m`` is the odd-moment rate
    of TRT (ignored by BGK), ``f*`` the force density (ignored without forcing). ``jz_sum`` is the
    sum of ``rho u_z`` over the swept nodes when ``spec.flux`` (else 0).
    """
    if spec in _LOADED:
        return _LOADED[spec]
    if spec.collision not in ("bgk", "trt"):
        raise ValueError(f"unknown collision operator {spec.collision!r}: choose bgk or trt")
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
