"""Command line: ``lbmpipe check SCENE...``, ``lbmpipe check-config CONFIG``, ``lbmpipe run SCENE --out DIR``,
``lbmpipe stability`` and ``lbmpipe document``.

Exit status: 0 success; 2 bad scene, bad arguments or a checkpoint of another scene; 3 output
directory already holds a finished run (``summary.json``) and ``--force`` was not given (unless
resuming from ``--checkpoint``); 4 the solver did not complete (status ``unstable``: the run-time
guard stopped a diverging run); 130 interrupted.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from lbmpipe.checkpoint import CheckpointError, read_head, scene_fingerprint
from lbmpipe.cost import for_host, predict
from lbmpipe.fields import bytes_per_sample, count_particles, memory_per_sample, sample_count
from lbmpipe.inputs import (InputError, available_memory, check_checkpoint_path, check_memory, check_writable_dir,
                            format_bytes, memory_estimate, out_dir_owner)
from lbmpipe.outputs import host, portable_path
from lbmpipe.pipeline_config import read_config
from lbmpipe.scene import Scene, SceneError, load_scene
from lbmpipe.units import LatticeParams, derive

EXIT_OK = 0
EXIT_BAD_SCENE = 2
EXIT_EXISTS = 3
EXIT_FAILED = 4
EXIT_INTERRUPTED = 130


def _flatten(prefix: str, value, out: list[tuple[str, str]]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else k, v, out)
    elif isinstance(value, list) and value and isinstance(value[0], dict):
        for i, v in enumerate(value):
            _flatten(f"{prefix}[{i}]", v, out)
    else:
        out.append((prefix, "null" if value is None else str(value)))


def _relevant(scene: Scene) -> dict:
    """The scene as a dict without unset optional keys and keys its kinds do not read."""
    data = scene.model_dump(mode="json")
    dom, drv, num = data["domain"], data["driving"], data["numerics"]
    if scene.domain.kind == "pipe":
        for key in ("size_mm", "walls", "moving_walls"):
            dom.pop(key)
    elif not dom["moving_walls"]:
        dom.pop("moving_walls")
    if scene.driving.kind != "body_force":
        drv.pop("acceleration_m_s2")
    if scene.numerics.collision != "trt":
        num.pop("trt_magic")

    def prune(d: dict) -> dict:
        return {k: prune(v) if isinstance(v, dict) else v for k, v in d.items() if v is not None}

    return prune(data)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _table(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}} = {v}" for k, v in rows)


#: where ``lbmpipe check`` looks for a calibrated cost model: the wall-time models of the production
#: levels' runs first (``lbmpipe.reproduction.runcost``), then the accuracy-cost study's
COST_MODEL_PATHS = (tuple(f"results/{lvl}/tables/cost_model.json" for lvl in ("credible", "paper"))
                    + tuple(f"results/{lvl}/study/cost_model.json" for lvl in ("paper", "quick", "smoke")))


def find_cost_model(explicit: str | None = None) -> tuple[dict | None, str | None]:
    """A fitted cost model (``lbmpipe.reproduction.runcost``: ``write`` or ``fit_cost_model``):
    ``explicit`` if given, else the first of ``COST_MODEL_PATHS`` under the current directory."""
    import json

    if explicit and not Path(explicit).is_file():  # a named model that is not there is an error, not "no model"
        raise InputError("--cost-model", f"{explicit} is not a file", "give the path of a cost_model.json (e.g. "
                         f"{COST_MODEL_PATHS[0]}), or leave --cost-model out to use the first one found")
    for cand in ([explicit] if explicit else list(COST_MODEL_PATHS)):
        path = Path(cand)
        if path.is_file():
            try:
                model = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, ValueError) as exc:
                raise InputError("--cost-model" if explicit else str(path), f"{path} is not a readable JSON file "
                                 f"({type(exc).__name__}: {' '.join(str(exc).split())[:120]})",
                                 "give a cost_model.json written by the pipeline (snakemake regenerates it)") from None
            if not isinstance(model, dict):
                raise InputError("--cost-model" if explicit else str(path), f"{path} holds a JSON "
                                 f"{type(model).__name__}, not a cost model (a JSON object)",
                                 "give a cost_model.json written by the pipeline") from None
            return model, str(path)
    return None, None


def format_report(scene: Scene, params: LatticeParams, source: str = "", cost_model: tuple | None = None) -> str:
    """Human-readable resolved scene and derived lattice parameters; with ``cost_model`` (the
    model, its path) also the run time that the study's calibrated model predicts."""
    rows: list[tuple[str, str]] = []
    _flatten("", _relevant(scene), rows)
    u = params.units
    derived = [
        ("shape (nx, ny, nz)", " x ".join(str(n) for n in params.shape)),
        ("fluid nodes", f"{params.fluid_nodes:,}"),
        ("nu_lu", f"{params.nu_lu:.6g}  ({u.viscosity_phys(params.nu_lu):.4g} m^2/s)"),
        ("tau", f"{params.tau:.4f}"),
        ("omega", f"{params.omega:.6g}"),
    ]
    if scene.numerics.collision == "trt":
        derived.append(("omega_minus", f"{params.omega_minus:.6g}  (trt_magic {scene.numerics.trt_magic:g})"))
    derived += [
        ("u_mean_lu", f"{params.u_mean_lu:.4g}  ({u.velocity_phys(params.u_mean_lu):.4g} m/s)"),
        ("u_max_lu", f"{params.u_max_lu:.4g}  ({u.velocity_phys(params.u_max_lu):.4g} m/s)"),
        ("Mach", f"{params.mach_max:.3f}  (limit {scene.numerics.mach_limit:g})"),
        ("u_max estimate", params.u_max_basis),
        ("Re", f"{params.reynolds:.4g}  (length {params.char_length_lu:g} nodes)"),
    ]
    if any(params.accel_lu):
        derived.append(("accel_lu", "(" + ", ".join(f"{a:.4g}" for a in params.accel_lu) + ")"))
    if params.flow_rate_lu is not None:
        derived.append(("flow_rate_lu", f"{params.flow_rate_lu:.6g}"))
    for side, v in params.wall_velocities_lu.items():
        derived.append((f"wall {side} velocity_lu", "(" + ", ".join(f"{c:.4g}" for c in v) + ")"))
    derived += [
        ("steps", f"{params.n_steps:,}  (spin-up {params.spinup_steps:,}, sample every {params.sample_every:,})"),
        ("estimated run time", f"{_duration(params.estimated_seconds)}  (lbmpipe.cost: {params.fluid_nodes * params.n_steps:.3g} fluid node "
                               f"updates at the reference throughput{_particles_not_counted(scene, params)})"),
        ("estimated memory", _memory_text(scene)),
    ]
    if scene.outputs.fields is not None:
        derived.append(("field output", _field_output_size(scene, params)))
    if cost_model is not None and cost_model[0] is not None:
        derived.append(("predicted run time", _predicted_text(scene, params, *cost_model)))
    text = [f"Scene {scene.name}" + (f"  ({source})" if source else ""), _table(rows), "", "Derived lattice parameters", _table(derived)]
    if params.warnings:
        text += ["", "Warnings"] + [f"  - {w}" for w in params.warnings]
    return "\n".join(text)


def _particles_not_counted(scene: Scene, params: LatticeParams) -> str:
    """What the fluid-only estimate (``lbmpipe.cost``) leaves out: with particles, their coupling and
    collisions (it counts fluid node updates only, so it is a lower bound)."""
    if scene.particles is None:
        return ""

    n = count_particles(scene, params)
    if n == 0:
        return ""
    return (f"; the {n:,} particle{'s' if n != 1 else ''}' coupling and collisions are not counted: a lower bound, "
            "see the predicted run time")


def _predicted_text(scene: Scene, params: LatticeParams, model: dict, path: str) -> str:
    """The cost model's wall-time prediction (``lbmpipe.cost.predict``) with the error its fit
    was validated to: a level's production runs held out by family, or the study's runs."""
    cpu = host()["cpu"]
    used, own = for_host(model, cpu)
    if "s_per_step" in used:  # fitted to a level's production runs, validated with each family held out
        err, err_med = (float("nan") if used.get(k) is None else float(used[k])  # null: not measured
                        for k in ("median_abs_rel_error", "median_abs_rel_error_median_share"))
        share = float(used.get("median_cpu_share", 1.0))
        here = int((model.get("runs_by_host") or {}).get(cpu, 0))
        runs = (f"{used.get('n_validated', 0)} production runs on this processor ({cpu}) held out of the fit" if own else
                f"{used.get('n_validated', 0)} production runs held out of the fit; {here} on this processor ({cpu}), too "
                f"few families to validate its own coefficients, and its fluid step may cost another time per node")
        text = (f"{_duration(predict(scene, params, used))} wall with a core per thread of its own, "
                f"{_duration(predict(scene, params, used, share))} with the {share:.2f} of a core the "
                f"production runs got  (median error {100 * err:.0f} % given a run's share, {100 * err_med:.0f} % at the "
                f"median share, on {runs}: {path})")
        if (scene.run.threads or 1) not in model.get("threads_measured", [1]):
            text += f"; not validated at {scene.run.threads} threads"
        return text
    return (f"{_duration(predict(scene, params, used))}  (cost model of {model.get('n_runs', '?')} runs, "
            f"rms error {100 * model.get('rel_rms_error', float('nan')):.0f} %: {path})")


def format_closing_summary(summary: dict, out: Path | str) -> str:
    """The lines ``lbmpipe run`` ends with: status, steps and simulated time, wall time, MLUPS and
    where the outputs are, from the run's summary dict (``summary.json``)."""
    status = summary.get("status", "unknown")
    steps, asked = summary.get("steps", 0), summary.get("steps_requested", summary.get("steps", 0))
    wall, setup = float(summary.get("wall_seconds", 0.0)), float(summary.get("setup_seconds", 0.0))
    threads = summary.get("threads")
    lines = [
        f"run {status}: {steps:,} of {asked:,} steps, {float(summary.get('simulated_seconds', 0.0)):.4g} s simulated",
        f"  wall time {_duration(wall)} stepping + {_duration(setup)} set-up, "
        f"{float(summary.get('mlups', 0.0)):.3g} MLUPS" + (f" on {threads} thread{'s' if threads != 1 else ''}"
                                                           if threads else ""),
    ]
    files = summary.get("files") or []
    lines.append(f"  outputs in {out}: " + ", ".join(["summary.json", *files]))
    return "\n".join(lines)


def _memory_text(scene: Scene) -> str:

    est = memory_estimate(scene)
    avail, source = available_memory()
    of = f" of {format_bytes(avail)} available ({source})" if avail is not None else ""
    return f"{format_bytes(est['bytes'])}{of}"


def _field_output_size(scene: Scene, params: LatticeParams) -> str:
    """Disk (and memory) per field sample and for the run (``lbmpipe.fields``)."""

    lat, parts = bytes_per_sample(scene, params)
    n = sample_count(scene, params)
    text = f"{lat / 1e6:.3g} MB lattice"
    if parts:
        text += f" + {parts / 1e6:.3g} MB particles ({count_particles(scene, params)} bodies)"
    return text + (f" per sample, {n} samples: {n * (lat + parts) / 1e9:.3g} GB on disk; about "
                   f"{memory_per_sample(scene, params) / 1e6:.3g} MB of memory while a sample is written")


def _load(path: str) -> tuple[Scene, LatticeParams]:
    scene = load_scene(path)
    check_memory(scene)  # before derive: a grid of billions of nodes is refused without allocating
    return scene, derive(scene)


def _cmd_check(args) -> int:
    status = EXIT_OK
    for i, path in enumerate(args.scenes):
        try:
            scene, params = _load(path)
        except SceneError as exc:
            print(f"{path}:\n{exc}", file=sys.stderr)
            status = EXIT_BAD_SCENE
            continue
        if i:
            print()
        print(format_report(scene, params, path, cost_model=find_cost_model(args.cost_model)))
    return status


def _cmd_run(args) -> int:
    try:
        scene, params = _load(args.scene)
    except SceneError as exc:
        print(f"{args.scene}:\n{exc}", file=sys.stderr)
        return EXIT_BAD_SCENE
    out = Path(args.out)
    resuming = args.checkpoint is not None and Path(args.checkpoint).exists()
    status = _check_out_owner(out, scene, args.force, resuming)
    if status:
        return status
    try:
        _prepare_paths(out, args)
    except InputError as exc:
        print(exc.line(), file=sys.stderr)
        return EXIT_BAD_SCENE
    if resuming:  # a bad or foreign checkpoint is refused before the simulation is built

        try:
            read_head(Path(args.checkpoint), scene_fingerprint(scene))
        except CheckpointError as exc:
            print(_checkpoint_line(exc), file=sys.stderr)
            return EXIT_BAD_SCENE
    threads_note = _apply_threads(scene)
    if threads_note and not args.quiet:
        print(threads_note)
    if not args.quiet:
        print(format_report(scene, params, args.scene))
        print(f"\nwriting to {out}")
    try:
        # heavy: the solver stack (every kernel module); `check` and `--help` never need it
        from lbmpipe.run import run_scene
    except ImportError as exc:
        print(f"the solver is not available: {exc}", file=sys.stderr)
        return EXIT_FAILED
    out.mkdir(parents=True, exist_ok=True)
    kwargs = {}
    if args.checkpoint is not None:
        kwargs = {"checkpoint": Path(args.checkpoint), "checkpoint_every_s": args.checkpoint_every_s,
                  "keep_checkpoint": args.keep_checkpoint}
        if resuming and not args.quiet:
            print(f"resuming from the checkpoint {args.checkpoint}")

    try:
        summary = run_scene(scene, params, out, progress=not args.quiet, max_steps=args.steps, **kwargs)
    except CheckpointError as exc:
        print(_checkpoint_line(exc), file=sys.stderr)
        return EXIT_BAD_SCENE
    except SceneError as exc:  # found only when the scene is built (a packing file that cannot be read)
        print(f"{args.scene}:\n{exc}", file=sys.stderr)
        return EXIT_BAD_SCENE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    status = (summary or {}).get("status")
    if summary and not args.quiet:
        print(format_closing_summary(summary, out))
    if status == "completed":
        return EXIT_OK
    if status == "interrupted":
        hint = (f"; rerun the same command to resume from {args.checkpoint}" if args.checkpoint is not None else "")
        print("run interrupted; partial results in " + str(out) + hint, file=sys.stderr)
        return EXIT_INTERRUPTED
    if summary.get("message"):
        print(summary["message"], file=sys.stderr)
    print(f"run did not complete (status {status!r}); see {out}", file=sys.stderr)
    return EXIT_FAILED


def _checkpoint_line(exc: Exception) -> str:
    """A CheckpointError as the one-line ``checkpoint error in --checkpoint: ... Fix: ...``."""
    text = " ".join(str(exc).split())
    msg, sep, fix = text.rpartition("; ")
    if not sep:
        msg, fix = text, "delete the checkpoint to start afresh"
    return f"checkpoint error in --checkpoint: {msg}. Fix: {fix}"


def _check_out_owner(out: Path, scene: Scene, force: bool, resuming: bool) -> int:
    """Exit status 3 (with one line) when ``out`` holds a run that must not be overwritten: a
    finished run of this scene without --force (unless resuming its interrupted run), or any run
    of another scene (name and fingerprint of its summary.json), even when a checkpoint of this
    scene is resumed; else 0."""

    owner = out_dir_owner(out) if out.is_dir() else None
    if owner is None or force:
        return EXIT_OK
    if owner["fingerprint"] != _summary_fingerprint(scene):
        print(f"output error in --out: {out} holds a run of another scene ({owner['name']!r}, status "
              f"{owner['status']!r}); nothing was changed. Fix: choose another --out, or pass --force to overwrite it",
              file=sys.stderr)
        return EXIT_EXISTS
    if owner["status"] == "completed" or not resuming:
        print(f"output error in --out: {out} already holds a run of this scene (summary.json, status "
              f"{owner['status']!r}); nothing was changed. Fix: use --force to overwrite it, choose another --out"
              + ("" if owner["status"] == "completed" else ", or resume it with --checkpoint"), file=sys.stderr)
        return EXIT_EXISTS
    return EXIT_OK


def _summary_fingerprint(scene: Scene) -> str:
    """Fingerprint of the scene as ``outputs.write_summary`` records it (packing files named from
    the working directory), to compare with a summary.json's."""

    doc = scene.model_dump(mode="json")
    for g in (doc.get("particles") or {}).get("packed") or []:
        if g.get("file"):
            g["file"] = portable_path(g["file"])
    return scene_fingerprint(doc)


def _prepare_paths(out: Path, args) -> None:
    """--out is a folder we can write in (created now, before the first step) and --checkpoint a
    file path in a writable folder; InputError otherwise."""

    check_writable_dir(out, "--out")
    if args.checkpoint is not None:
        ck = Path(args.checkpoint)
        check_checkpoint_path(ck)
        check_writable_dir(ck.parent, "--checkpoint")


def _apply_threads(scene: Scene) -> str:
    """Set numba's thread count to the scene's ``run.threads`` (at most the threads numba
    started with, NUMBA_NUM_THREADS); returns a note when it had to be capped. The results do not
    depend on it (the sweep's chunks are fixed)."""
    want = scene.run.threads
    if want is None:
        return ""
    import numba

    avail = numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(min(want, avail))
    if want > avail:
        return f"run.threads = {want} but numba has {avail} threads (NUMBA_NUM_THREADS): using {avail}"
    return ""


def _cmd_check_config(args) -> int:
    """``lbmpipe check-config CONFIG``: the checks the Snakefile makes before any job."""
    # heavy: the reproduction layer (pandas, matplotlib, jsonschema), for this subcommand only
    from lbmpipe.reproduction.cases import CONFIG_SCHEMA, config_problems

    path = Path(args.config)
    try:
        config = read_config(path)  # strict: a key given twice is refused, as in a scene
    except InputError as exc:
        print(exc.line(), file=sys.stderr)
        return EXIT_BAD_SCENE
    schema = Path(args.root) / CONFIG_SCHEMA
    problems = config_problems(config, schema)
    for line in problems:
        print(line, file=sys.stderr)
    if not problems:
        print(f"{path}: valid ({len(config['cases'])} cases, {len(config['fidelities'])} fidelity levels)")
    return EXIT_BAD_SCENE if problems else EXIT_OK


def _cmd_stability(args) -> int:
    # heavy: the reproduction layer (pandas, matplotlib), for this subcommand only
    from lbmpipe.reproduction import stability

    cases = stability.suite()
    if args.cases:
        unknown = sorted(set(args.cases) - {c.name for c in cases})
        if unknown:
            print(f"unknown case(s) {unknown}; the suite has {[c.name for c in cases]}", file=sys.stderr)
            return EXIT_BAD_SCENE
        cases = [c for c in cases if c.name in args.cases]
    settings = stability.fidelity_settings(None, args.fidelity)
    df = stability.run_suite(settings, Path(args.out) if args.out else None, cases=cases, threads=args.threads,
                             log=None if args.quiet else print)
    if df.attrs.get("recommendation") and not args.quiet:
        print(df.attrs["recommendation"])
    return EXIT_OK if (df["status"] != "violated").all() else EXIT_FAILED


def _cmd_document(args) -> int:
    # Rebuilds only the document from the results already on disk: after a code change moves a
    # linked definition, this refreshes the links without rerunning a single case.
    # heavy: the reproduction layer (pandas, matplotlib, jinja2), for this subcommand only
    from .reproduction.literate import build_checked_document

    root = Path(args.root).resolve()
    fid_dir = root / "results" / args.fidelity
    if not fid_dir.is_dir():
        print(f"no results at {fid_dir}: run `snakemake -c2 --config fidelity={args.fidelity}` first", file=sys.stderr)
        return EXIT_FAILED
    config = read_config(root / "config.yaml")  # strict, as the Snakefile reads it; InputError: one line, exit 2
    out, stale = build_checked_document(root, args.fidelity, config)
    for problem in stale:
        print(f"stale link: {problem}", file=sys.stderr)
    print(f"wrote {out.relative_to(root)} and {out.with_suffix('.html').relative_to(root)}")
    return EXIT_FAILED if stale else EXIT_OK


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of every other bad input (status 2), not usage + error."""

    def error(self, message: str, prog: str | None = None):
        msg = " ".join(message.split())
        where = "the command line"
        if msg.startswith("argument "):
            where, _, msg = msg[len("argument "):].partition(": ")
        self.exit(EXIT_BAD_SCENE, f"argument error in {where}: {msg}. Fix: see '{prog or self.prog} --help'\n")

    def parse_args(self, args=None, namespace=None):
        # an unknown option after a command is found by this (the top) parser: point to the command's help
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(parsed, "command", None)
            self.error(f"unrecognized arguments: {' '.join(extras)}", f"{self.prog} {command}" if command else None)
        return parsed


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number of seconds >= 0 (e.g. 300; 0: at every "
                                         "sample)")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be at least 1")
    return value


def _nonempty_path(text: str) -> str:
    if not text.strip() or "\0" in text:
        raise argparse.ArgumentTypeError(f"{text!r} is not a path")
    return text


#: every command with its arguments and a one-line description; ``lbmpipe --help`` lists them all
COMMANDS = {
    "check": ("SCENE...", "validate scene files and print the derived lattice parameters"),
    "run": ("SCENE --out DIR", "run a scene: progress bar, outputs in DIR, closing summary"),
    "check-config": ("CONFIG", "validate a pipeline config (as the Snakefile does before any job)"),
    "stability": ("", "run the stability suite (lbmpipe.reproduction.stability) and print or write its table"),
    "document": ("", "rebuild paper/reproduction_<level>.md/.html from results/<level>/ (no case is rerun)"),
}


def _description() -> str:
    width = max(len(f"{name} {args}".strip()) for name, (args, _) in COMMANDS.items()) + 2
    rows = "\n".join(f"  {f'{name} {args}'.strip():<{width}}{text}" for name, (args, text) in COMMANDS.items())
    return ("lbmpipe: lattice Boltzmann runs of rigid particles in pipe and box flows, from YAML scene\n"
            "files in physical units (docs/scene.md).\n\ncommands:\n" + rows +
            "\n\n'lbmpipe COMMAND --help' gives the options of one command.")


EPILOG = ("exit status: 0 success; 2 bad scene or arguments; 3 DIR already holds a finished run\n"
          "(no --force); 4 the run did not complete; 130 interrupted.")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="lbmpipe", usage="lbmpipe [-h] COMMAND ...", description=_description(),
                                     epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    # the commands are listed in the description; argparse's own list would repeat them
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", help=argparse.SUPPRESS,
                                parser_class=_Parser, prog="lbmpipe")  # a command's name: `lbmpipe run`
    p_check = sub.add_parser("check", help=COMMANDS["check"][1], description=COMMANDS["check"][1])
    p_check.add_argument("scenes", nargs="+", metavar="SCENE", help="YAML scene file(s); see docs/scene.md")
    p_check.add_argument("--cost-model", default=None, metavar="JSON",
                         help="cost model: a level's tables/cost_model.json or the accuracy-cost study's (default: the first of "
                              + ", ".join(COST_MODEL_PATHS) + " that exists)")
    p_check.set_defaults(func=_cmd_check)
    p_cc = sub.add_parser("check-config", help=COMMANDS["check-config"][1], description=COMMANDS["check-config"][1])
    p_cc.add_argument("config", metavar="CONFIG", help="pipeline config YAML, e.g. config.yaml")
    p_cc.add_argument("--root", default=str(Path(__file__).resolve().parents[1]),
                      help="repository root holding " + "workflow/schemas/config.schema.yaml (default: this checkout)")
    p_cc.set_defaults(func=_cmd_check_config)
    p_run = sub.add_parser("run", help=COMMANDS["run"][1], description=COMMANDS["run"][1])
    p_run.add_argument("scene", metavar="SCENE", help="YAML scene file")
    p_run.add_argument("--out", required=True, metavar="DIR", type=_nonempty_path, help="output directory")
    p_run.add_argument("--force", action="store_true", help="overwrite a DIR that already holds summary.json")
    p_run.add_argument("--steps", type=_positive_int, default=None, metavar="N", help="stop after N steps (smoke tests)")
    p_run.add_argument("--quiet", action="store_true", help="no report, no progress bar")
    p_run.add_argument("--checkpoint", default=None, metavar="PATH", type=_nonempty_path,
                       help="checkpoint file: resume from it if it exists (same scene only), write the state to it "
                            "every --checkpoint-every-s seconds and at Ctrl-C, remove it on completion; resuming "
                            "is allowed into a DIR whose summary.json is from the interrupted run")
    p_run.add_argument("--checkpoint-every-s", type=_seconds, default=300.0, metavar="S",
                       help="wall-clock seconds between checkpoints (default 300)")
    p_run.add_argument("--keep-checkpoint", action="store_true",
                       help="keep the checkpoint (with the final state) when the run completes")
    p_run.set_defaults(func=_cmd_run)
    p_st = sub.add_parser("stability", help=COMMANDS["stability"][1], description=COMMANDS["stability"][1])
    p_st.add_argument("--fidelity", default="smoke", choices=["smoke", "quick", "paper"],
                      help="lattice spacing and step counts of the suite (default smoke)")
    p_st.add_argument("--cases", nargs="+", default=None, metavar="CASE", help="run only these cases")
    p_st.add_argument("--out", default=None, metavar="CSV", help="write the table here")
    p_st.add_argument("--threads", type=int, default=1, help="numba threads (default 1)")
    p_st.add_argument("--quiet", action="store_true")
    p_st.set_defaults(func=_cmd_stability)
    p_doc = sub.add_parser("document", help=COMMANDS["document"][1], description=COMMANDS["document"][1])
    p_doc.add_argument("--fidelity", default="paper", help="results level to read (default paper)")
    p_doc.add_argument("--root", default=".", help="repository root (default: current directory)")
    p_doc.set_defaults(func=_cmd_document)
    return parser


def run_cli(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the command; returns the exit status (argparse errors exit 2)."""
    args = build_parser().parse_args(argv)
    return args.func(args)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point; always ends with SystemExit(status). Any error that escaped
    the checks above still ends in one line (set LBMPIPE_TRACEBACK=1 for the traceback)."""
    import os

    try:
        status = run_cli(argv)
    except (SceneError, InputError) as exc:
        print(str(exc), file=sys.stderr)
        status = EXIT_BAD_SCENE
    except MemoryError:
        print("error: out of memory. Fix: check `lbmpipe check SCENE` for the memory estimate, and use a coarser "
              "numerics.dx_mm or fewer particles", file=sys.stderr)
        status = EXIT_FAILED
    except Exception as exc:  # noqa: BLE001 - the last line of defence, reported as a bug
        if os.environ.get("LBMPIPE_TRACEBACK"):
            raise
        print(f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}. Fix: this is a bug in "
              "lbmpipe; rerun with LBMPIPE_TRACEBACK=1 and report the traceback", file=sys.stderr)
        status = EXIT_FAILED
    raise SystemExit(status)
