#!/usr/bin/env python
"""Throughput of lbmpipe's fluid-only step, beside the machine's copy bandwidth (roofline) and
lbmpy's generated D3Q15 BGK kernel, all measured in one interleaved run.

    python benchmarks/fluid.py              # full run, a few minutes
    python benchmarks/fluid.py --quick      # smoke run, smaller domains, fewer repetitions
    python benchmarks/fluid.py --json out.json

Figures are MLUPS (million fluid-node updates per second), the median of ``--reps`` repetitions
after warm-up. The repetitions of all contenders are interleaved (one of each per round, order
rotated), so load from other jobs on a shared machine hits them alike and the ratios stay
comparable. See benchmarks/README.md for what each figure means.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from numba import njit, prange

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import (  # noqa: E402
    Contender,
    LoadMonitor,
    available_threads,
    calibrate,
    copy_memcpy,
    copy_plain,
    fmt_bytes,
    last_level_cache_bytes,
    machine_info,
    measure_interleaved,
    set_threads,
)

from lbmpipe import effects  # noqa: E402
from lbmpipe.fluid import boundaries  # noqa: E402
from lbmpipe.fluid.lattice import get_lattice  # noqa: E402
from lbmpipe.solver import Simulation  # noqa: E402
from lbmpipe.units import trt_omega_minus  # noqa: E402

LATTICE = "D3Q15"
OMEGA = 1.0 / 0.8  # tau = 0.8, the value the brief fixes for the comparison
ITEMSIZE = {"float64": 8, "float32": 4}
MARK = {"quiet": "", "shared": "~", "disturbed": "*"}


def bytes_per_node(q: int, precision: str) -> int:
    """Minimum memory traffic of one node update: read q populations, write q (no write-allocate,
    as the copy bandwidth is counted): 240 B for D3Q15 in float64, 120 B in float32."""
    return 2 * q * ITEMSIZE[precision]


# --------------------------------------------------------------------------------------------
# lbmpipe contenders


def lbmpipe_box(n: int, threads: int, collision: str, precision: str) -> tuple[Simulation, int]:
    set_threads(threads)  # Simulation sizes its work chunks from the current thread count
    lat = get_lattice(LATTICE)
    grid = boundaries.box_grid(lat, (n, n, n), (False, False, False))
    om_m = trt_omega_minus(1.0 / OMEGA) if collision == "trt" else None
    sim = Simulation.build(grid, collision=collision, omega=OMEGA, omega_minus=om_m, precision=precision)
    return sim, n**3


def lbmpipe_pipe(n_d: int, n_len: int, threads: int, precision: str = "float64") -> tuple[Simulation, int]:
    set_threads(threads)
    lat = get_lattice(LATTICE)
    grid = boundaries.pipe_grid(lat, n_d, n_len)
    walls = effects.wall_effects(grid, "bounce_back", {})
    sim = Simulation.build(grid, collision="bgk", omega=OMEGA, precision=precision, extra_effects=walls)
    return sim, grid.n_fluid


# --------------------------------------------------------------------------------------------
# lbmpy contender


@njit(parallel=True, cache=True)
def periodic_ghosts(a, q_lo_x, q_hi_x, q_lo_y, q_hi_y, q_lo_z, q_hi_z):
    """Periodic ghost layers of ``a[q, z, y, x]`` (one ghost layer on each side), filled only for
    the populations the pull kernel reads from each ghost face: the low x ghost holds those with
    e_x = +1 (pulled from x - 1), the high one those with e_x = -1; likewise in y and z.

    Three passes (x faces, then y faces including the x ghosts, then z faces including both) fill
    the edge and corner ghosts that the diagonal D3Q15 links read, with one contiguous copy per
    face instead of one per neighbour direction.
    """
    _, Z, Y, X = a.shape
    nq = q_lo_x.shape[0]
    for t in prange(nq * Z):
        k, z = t // Z, t % Z
        ql, qh = q_lo_x[k], q_hi_x[k]
        for y in range(Y):
            a[ql, z, y, 0] = a[ql, z, y, X - 2]
            a[qh, z, y, X - 1] = a[qh, z, y, 1]
    for t in prange(nq * Z):
        k, z = t // Z, t % Z
        ql, qh = q_lo_y[k], q_hi_y[k]
        for x in range(X):
            a[ql, z, 0, x] = a[ql, z, Y - 2, x]
            a[qh, z, Y - 1, x] = a[qh, z, 1, x]
    for t in prange(nq * Y):
        k, y = t // Y, t % Y
        ql, qh = q_lo_z[k], q_hi_z[k]
        for x in range(X):
            a[ql, 0, y, x] = a[ql, Z - 2, y, x]
            a[qh, Z - 1, y, x] = a[qh, 1, y, x]


class LbmpyBox:
    """lbmpy's D3Q15 BGK on a periodic box, two arrays, stream-pull-collide.

    Arrays use lbmpy's default ``fzyx`` layout (populations outermost, x fastest) with one ghost
    layer; the kernel sweeps the interior. ``base[q, z, y, x]`` is the C-contiguous storage and
    ``view[x, y, z, q]`` the index order pystencils expects.
    """

    def __init__(self, shape: tuple[int, int, int], precision: str):
        from lbmpy import LBStencil, Stencil

        self.stencil = LBStencil(Stencil[LATTICE])
        self.dirs = np.array([tuple(d) for d in self.stencil], dtype=np.int64)
        q = self.stencil.Q
        nx, ny, nz = shape
        self.shape = shape
        self.precision = precision
        self.src = np.zeros((q, nz + 2, ny + 2, nx + 2), dtype=precision)
        self.dst = np.zeros_like(self.src)
        w = self._weights()
        for i in range(q):  # fluid at rest, rho = 1: same arithmetic as any state, no denormals
            self.src[i] = w[i]
            self.dst[i] = w[i]
        # lo-x, hi-x, lo-y, hi-y, lo-z, hi-z ghost faces: populations pulled from them
        self.ghost_q = [np.nonzero(self.dirs[:, ax] == sign)[0].astype(np.int64)
                        for ax in range(3) for sign in (1, -1)]
        from pystencils.slicing import get_periodic_boundary_functor

        neighbours = [d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)]
        neighbours = [tuple(int(c) - 1 for c in d) for d in neighbours]
        # What lbmpy's own LatticeBoltzmannStep does on a periodic serial domain: numpy copies
        # of all q populations for each of the 26 neighbour slabs (SerialDataHandling sync).
        self._lbmpy_sync = get_periodic_boundary_functor(neighbours, ghost_layers=1)

    def _weights(self) -> np.ndarray:
        lat = get_lattice(LATTICE)
        w = np.empty(len(self.dirs))
        for i, d in enumerate(self.dirs):
            j = int(np.nonzero((lat.e == d).all(axis=1))[0][0])
            w[i] = lat.w[j]
        return w

    @staticmethod
    def view(base: np.ndarray) -> np.ndarray:
        return base.transpose(3, 2, 1, 0)

    def sync(self, mode: str) -> None:
        if mode == "exchange":
            periodic_ghosts(self.src, *self.ghost_q)
        elif mode == "lbmpy":
            self._lbmpy_sync(self.view(self.src))
        elif mode != "none":
            raise ValueError(mode)

    def swap(self) -> None:
        self.src, self.dst = self.dst, self.src

    def runner(self, kernel, mode: str):
        def run(k: int) -> None:
            for _ in range(k):
                self.sync(mode)
                kernel(src=self.view(self.src), dst=self.view(self.dst))
                self.swap()

        return run


def lbmpy_kernel(precision: str, threads: int, simd: bool):
    """Compile lbmpy's textbook D3Q15 BGK (stream-pull + collide, two fields, fzyx layout).

    ``simd=True``: pystencils' own intrinsics vectoriser for the host CPU (the widest vector
    registers it supports, e.g. AVX-512); ``simd=False``: plain C left to gcc -O3/-Ofast with
    -march=native. OpenMP with ``threads`` threads baked into the pragma, so kernels for 1 and 2
    threads coexist in one process. Returns (function, C code).
    """
    import pystencils as ps
    from lbmpy import LBMConfig, LBMOptimisation, LBStencil, Method, Stencil, create_lb_ast

    cfg = ps.CreateKernelConfig(target=ps.Target.CurrentCPU if simd else ps.Target.GenericCPU,
                                default_dtype=precision)
    cfg.cpu.openmp.enable = True
    cfg.cpu.openmp.num_threads = threads
    if simd:
        cfg.cpu.vectorize.enable = True
        cfg.cpu.vectorize.assume_inner_stride_one = True
    lbm = LBMConfig(stencil=LBStencil(Stencil[LATTICE]), method=Method.SRT, relaxation_rate=OMEGA,
                    compressible=True, zero_centered=False, continuous_equilibrium=False)
    opt = LBMOptimisation(cse_global=True, field_layout="fzyx")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ast = create_lb_ast(lbm_config=lbm, lbm_optimisation=opt, config=cfg)
        code = ast.get_c_code() if hasattr(ast, "get_c_code") else ps.get_code_str(ast)
        fn = ast.compile()
    return fn, code


def simd_of(code: str) -> str:
    if "_mm512" in code:
        return "AVX-512"
    if "_mm256" in code:
        return "AVX2"
    if "_mm_" in code:
        return "SSE"
    return "compiler auto-vectorisation"


def validate_lbmpy(kernels: dict, shape=(12, 10, 8), steps: int = 4) -> dict:
    """Run lbmpipe and each lbmpy kernel from the same non-uniform state on a small periodic box
    and return the largest population difference after ``steps`` steps: proves both compute the
    same textbook BGK with the same periodic streaming (same physics, so the timing is fair)."""
    lat = get_lattice(LATTICE)
    nx, ny, nz = shape
    x, y, z = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    k = 2 * np.pi
    rho = 1.0 + 0.01 * np.sin(k * x / nx) * np.cos(k * z / nz)
    u = (0.03 * np.sin(k * y / ny), 0.02 * np.cos(k * z / nz), 0.025 * np.sin(k * (x / nx + y / ny)))
    out = {}
    for (precision, threads, simd), fn in kernels.items():
        set_threads(threads)
        grid = boundaries.box_grid(lat, shape, (False, False, False))
        sim = Simulation.build(grid, collision="bgk", omega=OMEGA, precision=precision)
        sim.set_equilibrium(rho, u)
        start = LbmpyBox(shape, precision)
        perm = [int(np.nonzero((lat.e == d).all(axis=1))[0][0]) for d in start.dirs]
        for i, j in enumerate(perm):  # lbmpipe f[q, x, y, z] -> lbmpy base[q, z, y, x]
            start.src[i, 1:-1, 1:-1, 1:-1] = sim.f[j, :, :, :nz].transpose(2, 1, 0)
        sim.step(steps)
        ref = sim.f[perm][:, :, :, :nz].transpose(0, 3, 2, 1)
        for mode in ("exchange", "lbmpy"):
            box = LbmpyBox(shape, precision)
            box.src[...] = start.src
            box.runner(fn, mode)(steps)
            diff = float(np.max(np.abs(box.src[:, 1:-1, 1:-1, 1:-1] - ref)))
            out[f"{precision}/t{threads}/{'simd' if simd else 'plain'}/{mode}"] = diff
    return out


# --------------------------------------------------------------------------------------------
# report


def fmt_row(cells, widths, aligns):
    return "  ".join(f"{c:{a}{w}}" for c, w, a in zip(cells, widths, aligns))


def print_table(header, rows, aligns):
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) if rows else len(str(h)) for i, h in enumerate(header)]
    print(fmt_row(header, widths, aligns))
    print(fmt_row(["-" * w for w in widths], widths, ["<"] * len(widths)))
    for r in rows:
        print(fmt_row([str(c) for c in r], widths, aligns))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke run: 32^3 box, 20x20x40 pipe, 3 short repetitions")
    ap.add_argument("--json", metavar="PATH", help="also write all figures to PATH (JSON)")
    ap.add_argument("--reps", type=int, help="timed repetitions per figure (default 5; 3 with --quick)")
    ap.add_argument("--rep-seconds", type=float, help="target length of one repetition (default 0.4 s; 0.05 with --quick)")
    ap.add_argument("--max-rounds", type=int,
                    help="rounds at most while collecting --reps usable repetitions of each contender (default 3 x reps)")
    ap.add_argument("--quiet-cores", type=float, default=0.15,
                    help="a repetition counts as disturbed when other processes used more than this many cores (default 0.15)")
    ap.add_argument("--max-minutes", type=float, default=20.0,
                    help="stop adding rounds after this many minutes of measurement (default 20)")
    ap.add_argument("--threads", default="1,2", help="thread counts, comma separated (default 1,2)")
    ap.add_argument("--no-lbmpy", action="store_true", help="skip the lbmpy comparison")
    args = ap.parse_args(argv)

    quick = args.quick
    n_box = 32 if quick else 64
    pipe_d, pipe_len = (20, 40) if quick else (50, 100)
    reps = args.reps or (3 if quick else 5)
    if reps < 3:
        ap.error("--reps must be at least 3 (the figures are medians)")
    rep_s = args.rep_seconds or (0.05 if quick else 0.4)
    warmup = 1 if quick else 2
    threads = [int(t) for t in args.threads.split(",")]
    if max(threads) > available_threads():
        print(f"note: numba allows at most {available_threads()} threads here; dropping larger counts")
        threads = [t for t in threads if t <= available_threads()] or [1]
    lat = get_lattice(LATTICE)
    q = lat.q
    t_start = time.perf_counter()
    say = lambda s: print(s, flush=True)  # noqa: E731

    # ---------------- contenders
    say(f"setting up (box {n_box}^3, pipe {pipe_d}x{pipe_d}x{pipe_len}, threads {threads}) ...")
    cons: list[Contender] = []

    sims = {}
    for t in threads:
        for coll, prec in (("bgk", "float64"), ("trt", "float64"), ("bgk", "float32")):
            sim, nodes = lbmpipe_box(n_box, t, coll, prec)
            sims[(coll, prec, t)] = sim
            cons.append(Contender(f"lbmpipe/box/{coll}/{prec}/t{t}", sim.step, nodes, t,
                                  dict(contender=f"lbmpipe {coll.upper()}", domain=f"box {n_box}^3 periodic",
                                       precision=prec, group="lbmpipe", collision=coll, kind="box")))
        sim, nodes = lbmpipe_pipe(pipe_d, pipe_len, t)
        cons.append(Contender(f"lbmpipe/pipe/bgk/float64/t{t}", sim.step, nodes, t,
                              dict(contender="lbmpipe BGK + bounce-back wall",
                                   domain=f"pipe {pipe_d}x{pipe_d}x{pipe_len} ({nodes} fluid)",
                                   precision="float64", group="lbmpipe", collision="bgk", kind="pipe")))
    f_bytes = sims[("bgk", "float64", threads[0])].f.nbytes  # one population array of the box

    # copy bandwidth: one array pair the size of the box's f/f_next, one pair well beyond the LLC
    llc = last_level_cache_bytes() or 64 * 2**20
    big_bytes = max(2 * llc, 256 * 2**20)
    for size_key, nbytes in (("ws", f_bytes), ("big", big_bytes)):
        n = int(nbytes // 8)
        a = np.full(n, 1.0)
        b = np.zeros(n)
        for t in threads:
            for kind in ("plain", "memcpy"):
                if kind == "plain":
                    run = (lambda k, a=a, b=b: [copy_plain(a, b, 1.0) for _ in range(k)])
                else:
                    run = (lambda k, a=a, b=b: [copy_memcpy(a, b) for _ in range(k)])
                cons.append(Contender(f"copy/{kind}/{size_key}/t{t}", run, 2.0 * n * 8, t,
                                      dict(group="copy", kind=kind, size=size_key, array_bytes=n * 8)))

    lbmpy_note = None
    lbmpy_info = {}
    validation = {}
    if args.no_lbmpy:
        lbmpy_note = "lbmpy comparison skipped (--no-lbmpy)"
    else:
        try:
            import lbmpy
            import pystencils
        except ImportError as exc:
            lbmpy_note = (f"lbmpy comparison skipped: {exc.name} is not installed "
                          "(install the optional extra: pip install -e '.[bench]')")
        if lbmpy_note is None:
            say(f"compiling lbmpy {lbmpy.__version__} / pystencils {pystencils.__version__} kernels "
                "(cached after the first run) ...")
            lbmpy_info = {"lbmpy": lbmpy.__version__, "pystencils": pystencils.__version__}
            boxes = {p: LbmpyBox((n_box,) * 3, p) for p in ("float64", "float32")}
            kernels = {}
            simd_ok = True
            for t in threads:
                for prec, simd in (("float64", True), ("float64", False), ("float32", True)):
                    if simd and not simd_ok:
                        continue
                    try:
                        fn, code = lbmpy_kernel(prec, t, simd)
                    except Exception as exc:  # e.g. no intrinsics backend for this CPU
                        if not simd:
                            raise
                        simd_ok = False
                        say(f"note: pystencils' vectoriser failed here ({exc}); using plain C only")
                        continue
                    kernels[(prec, t, simd)] = fn
                    if simd:
                        lbmpy_info[f"simd_{prec}"] = simd_of(code)
            validation = validate_lbmpy({k: v for k, v in kernels.items() if k[1] == threads[0]})
            for (prec, t, simd), fn in kernels.items():
                isa = lbmpy_info.get(f"simd_{prec}", "") if simd else "gcc auto-vec"
                modes = ["exchange", "lbmpy", "none"] if (prec == "float64" and simd) else ["exchange"]
                if not simd_ok and prec == "float64":
                    modes = ["exchange", "lbmpy", "none"]
                for mode in modes:
                    desc = {"exchange": "ghost exchange", "lbmpy": "lbmpy's own sync", "none": "kernel only, NOT periodic"}[mode]
                    ref = mode == "exchange" and (simd or not simd_ok)
                    cons.append(Contender(
                        f"lbmpy/box/bgk/{prec}/t{t}/{'simd' if simd else 'plain'}/{mode}",
                        boxes[prec].runner(fn, mode), n_box**3, t,
                        dict(contender=f"lbmpy BGK ({isa}, {desc})", domain=f"box {n_box}^3 periodic",
                             precision=prec, group="lbmpy", reference=ref, kind="box", mode=mode,
                             simd=simd)))

    # ---------------- measure
    say(f"warm-up and calibration of {len(cons)} contenders ...")
    calibrate(cons, rep_s, warmup=warmup)
    monitor = LoadMonitor()
    est = sum(rep_s * (c.n + 1) / c.n for c in cons)
    say(f"measuring: interleaved rounds of ~{est:.0f} s (more if disturbed) until each contender has {reps} "
        f"usable repetitions (not disturbed by other jobs) ...")
    whole = LoadMonitor()
    t_meas = time.perf_counter()
    rounds = measure_interleaved(cons, reps, monitor, max_rounds=args.max_rounds or 3 * reps,
                                 quiet_cores=args.quiet_cores, time_limit=60.0 * args.max_minutes, progress=say)
    whole_load = whole.read()
    meas_s = time.perf_counter() - t_meas

    # ---------------- report
    machine = machine_info()
    by_key = {c.key: c for c in cons}
    print()
    print(f"machine: {machine['cpu_model']} ({machine['cpu_model_source']}), {machine['cores_logical']} logical cores "
          f"({machine['cores_usable']} usable), L2 {fmt_bytes(machine['l2_bytes'] or 0)}/core, "
          f"LLC {fmt_bytes(machine['llc_bytes'] or 0)}, SIMD {'/'.join(machine['simd']) or '?'}")
    print(f"numba {machine['numba']} ({machine['numba_threading_layer']} threading layer) compiles for LLVM cpu "
          f"'{machine['llvm_cpu_name']}'" + (f"; lbmpy {lbmpy_info['lbmpy']}, pystencils {lbmpy_info['pystencils']}"
                                             if lbmpy_info else ""))
    print(f"run: {'QUICK smoke run, ' if quick else ''}after warm-up, up to {reps} usable timed repetitions per figure, "
          f"interleaved in rounds; figure = median of its quiet repetitions (>= 3) [~: of quiet + shared, "
          f"*: of all]; spread = (max - min) / median; reps = used/timed")
    n_timed = sum(c.meta["reps_total"] for c in cons)
    n_dist = sum(1 for c in cons for x in c.meta["samples"] if x["level"] == "disturbed")
    status = {c.key: c.meta["status"] for c in cons}
    load = {"quiet_cores_threshold": args.quiet_cores, "rounds": rounds, "repetitions_timed": n_timed,
            "repetitions_disturbed": n_dist, "status": status, "whole_measurement": whole_load}
    if whole_load.get("foreign_cores") is not None:
        print(f"load from other processes during the measurement: {whole_load['foreign_cores']:.2f} cores on average "
              f"(steal {whole_load['steal_cores']:.2f}); {n_dist} of {n_timed} timed repetitions were disturbed "
              f"(others took CPU time from our threads) and are left out")
    n_shared = sum(v == "shared" for v in status.values())
    n_bad = sum(v == "disturbed" for v in status.values())
    if n_shared:
        print(f"note: {n_shared} figures (marked ~) come from repetitions during which other jobs ran on the core(s) "
              "the contender left idle: they had their cores but shared caches and memory bandwidth")
    if n_bad:
        print(f"WARNING: {n_bad} figures (marked *) got fewer than 3 undisturbed repetitions: other jobs took CPU "
              "time from them, so they are too low (2-thread ones most). Repeat on a quieter machine, or raise "
              "--max-rounds / --max-minutes.")

    # bandwidth table
    print()
    print("copy bandwidth (numba parallel copy of one float64 array into another; GB/s counts bytes read + written):")
    bw_rows = []
    bandwidth = []
    for kind in ("plain", "memcpy"):
        for size_key in ("ws", "big"):
            for t in threads:
                c = by_key[f"copy/{kind}/{size_key}/t{t}"]
                nb = c.meta["array_bytes"]
                size_txt = f"2 x {fmt_bytes(nb)}" + (" (= box f, f_next)" if size_key == "ws" else
                                                     f" (> LLC {fmt_bytes(llc)})")
                kind_txt = "plain loads/stores" if kind == "plain" else "memcpy (numba lowers b[i]=a[i] to it)"
                bw_rows.append([kind_txt, size_txt, t, f"{c.median / 1e9:.1f}" + MARK[c.meta["status"]],
                                f"{100 * c.spread:.0f}%", f"{len(c.rates)}/{c.meta['reps_total']}"])
                bandwidth.append(dict(id=c.key, kind=kind, size=size_key, array_bytes=nb, threads=t,
                                      gb_s_median=c.median / 1e9, gb_s_reps=[r / 1e9 for r in c.rates],
                                      spread=c.spread, status=c.meta["status"], samples=c.meta["samples"]))
    print_table(["copy", "arrays", "threads", "GB/s", "spread", "reps"], bw_rows, ["<", "<", ">", ">", ">", ">"])
    roof = {}
    for t in threads:
        bw = by_key[f"copy/plain/ws/t{t}"].median
        roof[t] = {p: bw / bytes_per_node(q, p) / 1e6 for p in ITEMSIZE}
        bw_big = by_key[f"copy/plain/big/t{t}"].median
        print(f"roofline, {t} thread{'s' if t > 1 else ''}: working-set copy {bw / 1e9:.1f} GB/s -> "
              f"{roof[t]['float64']:.0f} MLUPS float64 ({bytes_per_node(q, 'float64')} B/node), "
              f"{roof[t]['float32']:.0f} MLUPS float32 ({bytes_per_node(q, 'float32')} B/node); "
              f"[beyond-LLC copy {bw_big / 1e9:.1f} GB/s -> {bw_big / bytes_per_node(q, 'float64') / 1e6:.0f} MLUPS float64]")
    print("the roofline uses the plain-store copy of the working-set size (the box's two population arrays)")

    # main table
    refs = {(c.meta["precision"], c.threads): c for c in cons if c.meta.get("reference")}
    rows = []
    table = []
    order = {"lbmpipe": 0, "lbmpy": 1}
    fluid = sorted((c for c in cons if c.meta.get("group") in order),
                   key=lambda c: (c.meta["precision"] != "float64", c.threads, c.meta["kind"] != "box",
                                  order[c.meta["group"]], c.meta.get("collision") == "trt", not c.meta.get("reference", False),
                                  c.key))
    for c in fluid:
        prec = c.meta["precision"]
        ref = refs.get((prec, c.threads))
        ratio = c.median / ref.median if (ref is not None and c.meta["kind"] == "box") else None
        share = c.median / 1e6 / roof[c.threads][prec]
        rows.append(dict(id=c.key, contender=c.meta["contender"], domain=c.meta["domain"], threads=c.threads,
                         precision=prec, nodes=c.work, mlups_median=c.median / 1e6,
                         mlups_reps=[r / 1e6 for r in c.rates], spread=c.spread, steps_per_rep=c.n,
                         status=c.meta["status"], samples=c.meta["samples"],
                         ratio_to_lbmpy=ratio, roofline_share=share,
                         lbmpy_reference=ref.key if ref is not None else None))
        table.append([c.meta["contender"], c.meta["domain"], c.threads, prec,
                      f"{c.median / 1e6:.1f}" + MARK[c.meta["status"]], f"{100 * c.spread:.0f}%",
                      f"{len(c.rates)}/{c.meta['reps_total']}", "-" if ratio is None else f"{ratio:.2f}",
                      f"{100 * share:.0f}%"])
    print()
    print("fluid-only step, MLUPS = million (fluid) node updates per second, median:")
    print_table(["contender", "domain", "threads", "precision", "MLUPS", "spread", "reps", "ratio to lbmpy",
                 "roofline"], table, ["<", "<", ">", "<", ">", ">", ">", ">", ">"])
    if refs:
        print("ratio to lbmpy: against 'lbmpy BGK (..., ghost exchange)' at the same threads and precision "
              "(box rows only; for TRT that is the cost relative to lbmpy's BGK)")
    if lbmpy_note:
        print(lbmpy_note)
    if validation:
        for prec in ("float64", "float32"):
            d = [v for k, v in validation.items() if k.startswith(prec)]
            if d:
                print(f"check ({prec}): lbmpy reproduces lbmpipe's BGK on a 12x10x8 periodic box, 4 steps, "
                      f"max |f_lbmpy - f_lbmpipe| = {max(d):.1e} ({len(d)} kernel/sync combinations)")

    # targets
    targets = {}
    print()
    for t in threads:
        box = by_key.get(f"lbmpipe/box/bgk/float64/t{t}")
        ref = refs.get(("float64", t))
        share = box.median / 1e6 / roof[t]["float64"]
        tgt = {"roofline_share": share, "roofline_ok": share >= 0.75}
        line = f"targets, {t} thread{'s' if t > 1 else ''}: box float64 BGK at {100 * share:.0f}% of roofline " \
               f"({'meets' if share >= 0.75 else 'misses'} 75%)"
        if ref is not None:
            ratio = box.median / ref.median
            tgt.update(ratio_to_lbmpy=ratio, lbmpy_ok=ratio >= 1.0)
            line += f"; {ratio:.2f} x lbmpy ({'meets' if ratio >= 1.0 else 'misses'} >= 1)"
        targets[str(t)] = tgt
        print(line)
    total_s = time.perf_counter() - t_start
    print(f"(measurement {meas_s:.0f} s, total {total_s:.0f} s)")

    if args.json:
        cost, cost_status = {}, {}
        for c in fluid:
            if c.meta["group"] == "lbmpipe":
                k = f"{c.meta['kind']}_{c.meta['collision']}_{c.meta['precision']}"
                cost.setdefault(k, {})[str(c.threads)] = c.median / 1e6
                cost_status.setdefault(k, {})[str(c.threads)] = c.meta["status"]
        doc = {
            "schema": "lbmpipe.benchmarks.fluid/1",
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "quick": quick,
            "settings": dict(lattice=LATTICE, omega=OMEGA, box=n_box, pipe=[pipe_d, pipe_d, pipe_len], reps=reps,
                             rep_seconds=rep_s, warmup=warmup, threads=threads),
            "machine": machine,
            "lbmpy": lbmpy_info or None,
            "lbmpy_note": lbmpy_note,
            "bandwidth": bandwidth,
            "roofline": {str(t): dict(basis="copy/plain/ws", gb_s=by_key[f"copy/plain/ws/t{t}"].median / 1e9,
                                      mlups=roof[t], bytes_per_node={p: bytes_per_node(q, p) for p in ITEMSIZE})
                         for t in threads},
            "rows": rows,
            "targets": targets,
            "validation_max_abs_diff": validation,
            "load": load,
            # What the pipeline's cost model reads: measured MLUPS of the whole lbmpipe step per
            # domain kind / collision / precision, keyed by thread count.
            "cost_model": {"fluid_mlups": cost, "status": cost_status},
            "seconds": {"measurement": meas_s, "total": total_s},
        }
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=1, default=lambda o: o.item() if hasattr(o, "item") else str(o)))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
