"""Bad input of every kind -- scene files, command-line arguments, checkpoints, output folders,
pipeline configs -- ends in one line naming the field (or argument, or file) and the fix, a
non-zero exit status and no traceback, in bounded time and memory (each case runs the CLI in a
subprocess under an address-space limit and a timeout), and touches nothing outside the run's
own output folder. Then the behaviours the corpus found missing: the collision model's periodic
rule applied identically by `check` and the run, the checkpoint kept until the outputs are
complete, `run.threads` honoured, guard messages that name the likeliest cause."""

from __future__ import annotations

import copy
import json
import os
import resource
import shutil
import subprocess
import sys
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
#: address space of one CLI process: Python, NumPy and pydantic fit well inside; a YAML bomb
#: (7.5 GB expanded) or a 1000 x 1000 x 2500 lattice (600 GB) would not
ADDRESS_SPACE = 2 * 2**30
TIMEOUT = 120  # s; generous for a loaded 2-core machine, a bound, not a benchmark

PIPE = {
    "name": "bad_pipe",
    "domain": {"kind": "pipe", "diameter_mm": 20.0, "length_mm": 20.0},
    "fluid": {"viscosity_m2_s": 1.0e-4},
    "driving": {"kind": "flow_rate", "flow_rate_m3_s": 1.5e-5},
    "numerics": {"dx_mm": 2.5, "dt_s": 2.5e-3, "mach_limit": 0.6},
    "run": {"duration_s": 0.05, "spinup_s": 0.01, "sample_interval_s": 0.01},
}
PAPER_PIPE = {**PIPE, "domain": {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 50.0}}


def _limits():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def _cli(args, cwd, env_extra=None, timeout=TIMEOUT, limits=True):
    """``lbmpipe ARGS`` in a subprocess, under the address-space limit unless ``limits`` is False
    (a run that compiles the particle kernels from a cold numba cache needs more)."""
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", **(env_extra or {})}
    env.pop("LBMPIPE_TRACEBACK", None)
    return subprocess.run([sys.executable, "-m", "lbmpipe", *map(str, args)], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout, preexec_fn=_limits if limits else None)


def _tree(root: Path, skip: Path | None = None) -> dict:
    """Every file and folder under ``root`` (but ``skip``) with its bytes and mtime."""
    out = {}
    for p in sorted(root.rglob("*")):
        if skip is not None and (p == skip or skip in p.parents):
            continue
        out[str(p.relative_to(root))] = (p.read_bytes(), p.stat().st_mtime_ns) if p.is_file() and not p.is_symlink() \
            else "dir"
    return out


def _scene_file(tmp: Path, data: dict, name: str = "scene.yaml") -> Path:
    path = tmp / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _with(base: dict, **changes) -> dict:
    """``base`` with dotted-path changes, e.g. ``_with(PIPE, **{"numerics.dx_mm": 1e-320})``."""
    data = copy.deepcopy(base)
    for key, value in changes.items():
        *parents, last = key.split(".")
        node = data
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return data


@dataclass
class Case:
    """``setup(tmp)`` writes the inputs and returns the CLI arguments; the run must exit with
    ``status`` and print exactly one line holding ``where`` (and ``Fix:``, and every ``also``)."""

    id: str
    setup: Callable[[Path], list]
    status: int
    where: str
    also: tuple = ()
    out: str | None = None  # the run's own output folder (may change), relative to tmp
    unchanged_out: bool = False  # the output folder must be left exactly as it was
    prefix: str = "error in"
    skip_if: Callable[[], str | None] = field(default=lambda: None)


# -- scene files ------------------------------------------------------------------------------

def _raw(text: bytes | str, name="scene.yaml"):
    def setup(tmp):
        path = tmp / name
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        return ["check", path]
    return setup


def _scene(data, cmd="check"):
    def setup(tmp):
        path = _scene_file(tmp, data)
        return [cmd, path] if cmd == "check" else ["run", path, "--out", tmp / "out", "--quiet"]
    return setup


_GOOD = yaml.safe_dump(PIPE, sort_keys=False)
_BOMB = "\n".join(["a: &a [x, x, x, x, x, x, x, x, x]"] + [
    f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefg", "bcdefgh")])
_BOMB_KNOWN = _BOMB + "\n" + _GOOD.replace("name: bad_pipe", "name: [*h, *h, *h, *h, *h, *h, *h, *h, *h]")
_BOMB_UNKNOWN = _BOMB + "\n" + _GOOD


def _two_cubes(**collisions):
    return _with(PAPER_PIPE, particles={"random": [{"shape": "cube", "edge_mm": 16.0, "count": 2}],
                                        "collisions": collisions})


SCENE_CASES = [
    Case("non_utf8_byte_in_a_comment", _raw(b"# caf\xe9\n" + _GOOD.encode()), 2, "scene.yaml",
         ("byte 0xe9 at line 1", "UTF-8")),
    Case("list_nested_20000_deep", _raw(_GOOD + "x: " + "[" * 20000 + "]" * 20000 + "\n"), 2, "scene.yaml",
         ("nests deeper than 40",)),
    Case("alias_bomb_as_the_value_of_a_known_field", _raw(_BOMB_KNOWN), 2, "scene.yaml", ("expands to more than",)),
    Case("alias_bomb_under_an_unknown_key", _raw(_BOMB_UNKNOWN), 2, "scene.yaml", ("expands to more than",)),
    Case("recursive_alias", _raw(_GOOD + "x: &r [1, *r]\n"), 2, "scene.yaml"),
    Case("file_of_two_megabytes", _raw(_GOOD + "#" * 2_000_000 + "\n"), 2, "scene.yaml", ("bytes",)),
    Case("missing_file", lambda tmp: ["check", tmp / "nope.yaml"], 2, "nope.yaml", ("cannot read",)),
    Case("scene_path_is_a_folder", lambda tmp: ["check", tmp], 2, "error in", ("folder",)),
    Case("empty_file", _raw(""), 2, "scene.yaml", ("mapping",)),
    Case("yaml_syntax_error", _raw("name: [unclosed\n"), 2, "scene.yaml", ("not valid YAML",)),
    Case("top_level_list", _raw("- a\n- b\n"), 2, "scene.yaml", ("mapping",)),
    Case("key_given_twice", _raw(_GOOD + "name: again\n"), 2, "name", ("given twice",)),
    Case("list_as_a_mapping_key", _raw(_GOOD + "fluid_extra:\n  ? [a, b]\n  : 1\n"), 2, "scene.yaml",
         ("line 20, column 5 is a list",)),
    Case("integer_of_5000_digits", _raw(_GOOD.replace("duration_s: 0.05", "duration_s: " + "9" * 5000)), 2,
         "scene.yaml", ("cannot read a value",)),
    Case("name_of_100000_characters", _scene(_with(PIPE, name="x y" * 50_000)), 2, "name", ("characters",)),
    Case("dx_mm_1e-320_overflows_the_node_count", _scene(_with(PIPE, **{"numerics.dx_mm": 1e-320})), 2,
         "numerics.dx_mm", ("spans",)),
    Case("grid_1000x1000x2500_above_available_memory",
         _scene(_with(PIPE, domain={"kind": "pipe", "diameter_mm": 1000.0, "length_mm": 2500.0},
                      **{"numerics.dx_mm": 1.0, "numerics.dt_s": 1e-3})), 2, "numerics.dx_mm",
         ("the run needs about", "GB")),
    Case("count_of_a_trillion_particles",
         _scene(_with(PIPE, particles={"random": [{"shape": "sphere", "diameter_mm": 4.0, "count": 10**12}]})), 2,
         "particles.random[0].count", ("times the domain's volume",)),
    Case("two_16mm_cubes_in_the_50mm_pipe_need_two_interaction_ranges", _scene(_two_cubes()), 2,
         "domain.length_mm", ("two interaction ranges", "at least 65 mm")),
    Case("explicit_cubes_overlapping_by_4mm",
         _scene(_with(PIPE, **{"domain.length_mm": 30.0},
                      particles={"bodies": [{"shape": "cube", "edge_mm": 5.0, "position_mm": [0, 0, 10]},
                                                  {"shape": "cube", "edge_mm": 5.0, "position_mm": [0, 0, 11]}]})),
         2, "particles.bodies[1].position_mm", ("overlaps particles.bodies[0]", "by 4 mm")),
    Case("explicit_cylinders_overlapping_across_the_period",
         _scene(_with(PIPE, particles={"bodies": [
             {"shape": "cylinder", "diameter_mm": 4.0, "length_mm": 4.0, "position_mm": [0, 0, 1]},
             {"shape": "cylinder", "diameter_mm": 4.0, "length_mm": 4.0, "position_mm": [0, 0, 18]}]})),
         2, "particles.bodies[1].position_mm", ("by 1 mm",)),
    Case("cube_3mm_into_the_pipe_wall",
         # a 6 mm cube turned 45 degrees about the axis: its corner on the x axis at 8.75736 + 3 sqrt(2) = 13 mm
         _scene(_with(PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 6.0, "position_mm": [8.75736, 0, 10],
                                                   "orientation": [0.9238795325112867, 0, 0, 0.3826834323650898]}]})),
         2, "particles.bodies[0].position_mm", ("reaches 3 mm into the pipe wall",)),
    Case("sphere_into_a_box_wall",
         _scene({**_with(PIPE, domain={"kind": "box", "size_mm": [20, 20, 20], "walls": {"y": "wall"}},
                         driving={"kind": "none"}),
                 "particles": {"bodies": [{"shape": "sphere", "diameter_mm": 6.0, "position_mm": [10, 1.0, 10]}]}}),
         2, "particles.bodies[0].position_mm", ("into the wall y-",)),
    Case("unknown_key_with_a_typo", _scene(_with(PIPE, **{"fluid.viscosity": 1e-4})), 2, "fluid.viscosity",
         ("did you mean",)),
    Case("viscosity_nan", _raw(_GOOD.replace("viscosity_m2_s: 0.0001", "viscosity_m2_s: .nan")), 2,
         "fluid.viscosity_m2_s", ("finite",)),
    Case("duration_as_text", _scene(_with(PIPE, **{"run.duration_s": "ten seconds"})), 2, "run.duration_s"),
    Case("spinup_longer_than_the_run", _scene(_with(PIPE, **{"run.spinup_s": 1.0})), 2, "run.spinup_s"),
    Case("diameter_not_a_multiple_of_dx", _scene(_with(PIPE, **{"domain.diameter_mm": 21.0})), 2,
         "domain.diameter_mm", ("multiple",)),
    Case("mach_number_above_the_limit", _scene(_with(PIPE, **{"numerics.dt_s": 0.05}, run={
        "duration_s": 1.0, "spinup_s": 0.1, "sample_interval_s": 0.1})), 2, "numerics.dt_s",
         ("Mach",)),
    Case("zero_quaternion",
         _scene(_with(PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 4.0, "position_mm": [0, 0, 10],
                                                   "orientation": [0, 0, 0, 0]}]})),
         2, "particles.bodies[0].orientation"),
    Case("run_of_a_scene_with_overlapping_bodies_refused_before_the_first_step",
         _scene(_with(PIPE, particles={"bodies": [{"shape": "sphere", "diameter_mm": 6.0, "position_mm": [0, 0, 10]},
                                                  {"shape": "sphere", "diameter_mm": 6.0, "position_mm": [0, 0, 12]}]}),
                cmd="run"), 2, "particles.bodies[1].position_mm", out="out"),
]


# -- command-line arguments -------------------------------------------------------------------

def _run_args(*extra, scene=PIPE):
    def setup(tmp):
        return ["run", _scene_file(tmp, scene), "--out", tmp / "out", "--quiet", *extra]
    return setup


def _check_with_cost_model(content: bytes | None):
    def setup(tmp):
        model = tmp / "cost_model.json"
        if content is not None:
            model.write_bytes(content)
        return ["check", _scene_file(tmp, PIPE), "--cost-model", model]
    return setup


ARG_CASES = [
    Case("checkpoint_every_nan", _run_args("--checkpoint", "c.npz", "--checkpoint-every-s", "nan"), 2,
         "--checkpoint-every-s", ("'nan'",), prefix="argument error in"),
    Case("checkpoint_every_negative", _run_args("--checkpoint", "c.npz", "--checkpoint-every-s=-5"), 2,
         "--checkpoint-every-s", ("'-5'",), prefix="argument error in"),
    Case("checkpoint_every_infinite", _run_args("--checkpoint-every-s", "inf"), 2, "--checkpoint-every-s",
         prefix="argument error in"),
    Case("steps_zero", _run_args("--steps", "0"), 2, "--steps", ("at least 1",), prefix="argument error in"),
    Case("steps_not_a_number", _run_args("--steps", "many"), 2, "--steps", ("whole number",),
         prefix="argument error in"),
    Case("unknown_option", _run_args("--fast"), 2, "the command line", ("--fast",), prefix="argument error in"),
    Case("missing_out", lambda tmp: ["run", _scene_file(tmp, PIPE)], 2, "the command line", ("--out",),
         prefix="argument error in"),
    Case("no_command", lambda tmp: [], 2, "the command line", prefix="argument error in"),
    Case("empty_out", lambda tmp: ["run", _scene_file(tmp, PIPE), "--out", ""], 2, "--out",
         ("Fix: see 'lbmpipe run --help'",), prefix="argument error in"),
    Case("cost_model_not_json", _check_with_cost_model(b'{"s_per_step": 1e-3,'), 2, "--cost-model",
         ("not a readable JSON file",), prefix="argument error in"),
    Case("cost_model_a_json_list", _check_with_cost_model(b"[1, 2]"), 2, "--cost-model", ("not a cost model",),
         prefix="argument error in"),
    Case("cost_model_path_that_does_not_exist", _check_with_cost_model(None), 2, "--cost-model",
         ("is not a file",), prefix="argument error in"),
]


# -- output folders and checkpoints -----------------------------------------------------------

def _out_is_file(tmp):
    (tmp / "out").write_text("not a folder\n")
    return ["run", _scene_file(tmp, PIPE), "--out", tmp / "out", "--quiet"]


def _out_under_file(tmp):
    (tmp / "file").write_text("x\n")
    return ["run", _scene_file(tmp, PIPE), "--out", tmp / "file" / "out", "--quiet"]


def _out_read_only(tmp):
    ro = tmp / "ro"
    ro.mkdir()
    scene = _scene_file(tmp, PIPE)
    if os.geteuid() == 0:  # root writes through permissions; an immutable folder stops it
        if subprocess.run(["chattr", "+i", str(ro)], capture_output=True).returncode != 0:
            pytest.skip("cannot make a folder unwritable for root here (no chattr +i)")
    else:
        ro.chmod(0o555)
    return ["run", scene, "--out", ro, "--quiet"]


def _checkpoint(content: bytes | None = None, maker=None, name="c.npz"):
    def setup(tmp):
        ck = tmp / name
        if maker is not None:
            maker(ck)
        else:
            ck.write_bytes(content)
        return ["run", _scene_file(tmp, PIPE), "--out", tmp / "out", "--quiet", "--checkpoint", ck]
    return setup


def _truncated_npz(path: Path):
    np.savez(path, a=np.arange(1000.0), __meta__=np.frombuffer(b'{"format": "x"}', dtype=np.uint8))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _foreign_run(tmp, status="completed", scene=None):
    """``tmp/out`` holding a finished run (summary.json, flow_rate.csv) of ``scene``."""
    from lbmpipe.scene import Scene

    out = tmp / "out"
    out.mkdir()
    doc = {"status": status, "scene": Scene.model_validate(scene or _with(PIPE, name="other_scene"))
           .model_dump(mode="json")}
    (out / "summary.json").write_text(json.dumps(doc))
    (out / "flow_rate.csv").write_text("t_s,q_m3_s\n0.01,1e-5\n")
    return out


def _other_scenes_run_with_this_scenes_checkpoint(tmp):
    _foreign_run(tmp)
    (tmp / "c.npz").write_bytes(b"a checkpoint of this scene")  # never read: the folder is refused first
    return ["run", _scene_file(tmp, PIPE), "--out", tmp / "out", "--quiet", "--checkpoint", tmp / "c.npz"]


def _this_scenes_finished_run(tmp):
    _foreign_run(tmp, scene=PIPE)
    return ["run", _scene_file(tmp, PIPE), "--out", tmp / "out", "--quiet"]


FILE_CASES = [
    Case("out_is_an_existing_file", _out_is_file, 2, "--out", ("existing file",), out="out", unchanged_out=True),
    Case("out_under_a_file", _out_under_file, 2, "--out", ("which is a file",), out="file"),
    Case("out_on_a_read_only_folder_fails_before_the_first_step", _out_read_only, 2, "--out", ("cannot write",),
         out="ro", unchanged_out=True),
    Case("checkpoint_truncated", _checkpoint(maker=_truncated_npz), 2, "--checkpoint", ("cannot read",), out="out"),
    Case("checkpoint_starting_like_a_zip", _checkpoint(b"PK\x03\x04" + b"\0" * 200), 2, "--checkpoint",
         ("cannot read",), out="out"),
    Case("checkpoint_of_text", _checkpoint(b"hello\n"), 2, "--checkpoint", ("cannot read",), out="out"),
    Case("checkpoint_npz_without_header", _checkpoint(maker=lambda p: np.savez(p, a=np.zeros(3))), 2, "--checkpoint",
         ("not an lbmpipe checkpoint",), out="out"),
    Case("checkpoint_bare_npy_array", _checkpoint(maker=lambda p: np.save(p, np.zeros(3)), name="c.npy"), 2,
         "--checkpoint", ("not an lbmpipe archive",), out="out"),
    Case("checkpoint_is_a_folder", _checkpoint(maker=lambda p: p.mkdir()), 2, "--checkpoint", ("is a folder",),
         out="out"),
    Case("checkpoint_under_a_file", lambda tmp: (tmp / "f").write_text("x") and
         ["run", _scene_file(tmp, PIPE), "--out", tmp / "out", "--quiet", "--checkpoint", tmp / "f" / "c.npz"],
         2, "--checkpoint", ("which is a file",), out="out"),
    Case("out_holds_another_scenes_run_and_this_scenes_checkpoint_is_given",
         _other_scenes_run_with_this_scenes_checkpoint, 3, "--out", ("another scene", "'other_scene'"), out="out",
         unchanged_out=True),
    Case("out_holds_this_scenes_finished_run", _this_scenes_finished_run, 3, "--out", ("status 'completed'",), out="out",
         unchanged_out=True),
]


# -- pipeline configs -------------------------------------------------------------------------

def _config(mutate=None, raw: bytes | None = None):
    def setup(tmp):
        path = tmp / "config.yaml"
        if raw is not None:
            path.write_bytes(raw)
        else:
            cfg = yaml.safe_load((ROOT / "config.yaml").read_text())
            mutate(cfg)
            path.write_text(yaml.safe_dump(cfg))
        return ["check-config", path, "--root", ROOT]
    return setup


#: the committed config with `fidelity:` on two lines (lines 5 and 6): YAML alone keeps the last
_CONFIG_FIDELITY_TWICE = (ROOT / "config.yaml").read_bytes().replace(b"\nfidelity:", b"\nfidelity: smoke\nfidelity:", 1)

CONFIG_CASES = [
    Case("config_fidelity_not_defined", _config(lambda c: c.update(fidelity="bogus")), 2, "fidelity",
         ("'bogus'",), prefix="config error in"),
    Case("config_negative_packing_budget", _config(lambda c: c.update(packing_max_seconds=-1)), 2,
         "packing_max_seconds", prefix="config error in"),
    Case("config_unknown_key_in_a_case", _config(lambda c: c["cases"]["flow_re9.4"].update(colisions=False)), 2,
         "cases.flow_re9.4", ("colisions",), prefix="config error in"),
    Case("config_reynolds_not_of_the_paper", _config(lambda c: c["cases"]["flow_re9.4"].update(reynolds=12)), 2,
         "cases.flow_re9.4.reynolds", prefix="config error in"),
    Case("config_case_with_a_cube_wider_than_the_pipe", _config(lambda c: c["cases"].update(
        big={"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 60, "concentration": 0.3}})), 2,
        "cases.big at fidelities.", ("particles.packed[0]",), prefix="config error in"),
    Case("config_not_utf8", _config(raw=b"fidelity: sm\xf6ke\n"), 2, "config.yaml", ("cannot read",),
         prefix="config error in"),
    Case("config_a_list", _config(raw=b"- a\n- b\n"), 2, "the config file", ("mapping",), prefix="config error in"),
    Case("config_key_given_twice", _config(raw=_CONFIG_FIDELITY_TWICE), 2, "fidelity", ("given twice", "line 6"),
         prefix="config error in"),
]

ALL = SCENE_CASES + ARG_CASES + FILE_CASES + CONFIG_CASES


def _error_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if " error in " in ln or ln.startswith(("error in", "argument error"))]


@pytest.mark.parametrize("case", ALL, ids=[c.id for c in ALL])
def test_bad_input_gets_one_line_naming_the_field_and_fix_and_touches_nothing_else(case, tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    try:
        args = case.setup(work)
        out = work / case.out if case.out else None
        before = _tree(tmp_path, skip=None if case.unchanged_out else out)
        t0 = time.perf_counter()
        res = _cli(args, cwd=work)
        seconds = time.perf_counter() - t0
        after = _tree(tmp_path, skip=None if case.unchanged_out else out)
    finally:
        if (work / "ro").exists() and os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(work / "ro")], capture_output=True)
    err = res.stderr
    assert "Traceback" not in err and "Traceback" not in res.stdout, err
    assert res.returncode == case.status, err
    lines = _error_lines(err)
    assert len(lines) == 1, err
    line = lines[0]
    assert case.prefix in line and "Fix:" in line and case.where in line, line
    for text in case.also:
        assert text in line, line
    assert len(line) < 600, line  # one readable line, whatever the size of the input
    assert before == after, "files outside the run's output folder changed"
    print(f"{case.id}: {seconds:.2f} s, status {res.returncode}: {line[:160]}")


def test_corpus_covers_every_class_with_at_least_40_cases():
    assert len(ALL) >= 40
    assert {len(SCENE_CASES) > 0, len(ARG_CASES) > 0, len(FILE_CASES) > 0, len(CONFIG_CASES) > 0} == {True}


# -- refused before allocating ----------------------------------------------------------------

@pytest.mark.parametrize("text", [_BOMB_KNOWN, _GOOD + "x: " + "[" * 20000 + "]" * 20000 + "\n"],
                         ids=["alias_bomb", "deep_list"])
def test_yaml_bomb_and_deep_nesting_are_refused_before_building_them(tmp_path, text):
    from lbmpipe.scene import SceneError, load_scene

    path = tmp_path / "s.yaml"
    path.write_text(text)
    tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    with pytest.raises(SceneError):
        load_scene(path)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 50 * 2**20  # the expanded bomb is 7.5 GB
    print(f"refused in {seconds:.3f} s ({cpu:.3f} s CPU), peak {peak / 2**20:.1f} MB")


def test_huge_grid_is_refused_by_the_memory_estimate_without_allocating():
    from lbmpipe.inputs import check_memory, memory_estimate
    from lbmpipe.scene import Scene, SceneError

    scene = Scene.model_validate(_with(PIPE, domain={"kind": "pipe", "diameter_mm": 1000.0, "length_mm": 2500.0},
                                       **{"numerics.dx_mm": 1.0, "numerics.dt_s": 1e-3}))
    est = memory_estimate(scene)
    # two D3Q15 float64 population arrays over 1000 x 1000 x 2502 nodes
    assert est["populations_bytes"] == 2 * 15 * 8 * 1000 * 1000 * 2502
    tracemalloc.start()
    with pytest.raises(SceneError, match="the run needs about"):
        check_memory(scene)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 10 * 2**20


def test_check_prints_the_memory_estimate(tmp_path):
    res = _cli(["check", _scene_file(tmp_path, PIPE)], cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "estimated memory" in res.stdout and "available" in res.stdout


# -- the collision model's periodic rule: one function for check and run ------------------------

def test_one_free_body_or_no_pairs_needs_no_two_interaction_ranges_at_check():
    from lbmpipe.scene import Scene

    one = _with(PAPER_PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 16.0, "position_mm": [0, 0, 25]}]})
    Scene.model_validate(one)  # one free 16 mm cube in the 50 mm long pipe
    Scene.model_validate(_two_cubes(pairs=False))
    Scene.model_validate(_two_cubes(enabled=False))


def test_check_applies_exactly_the_runs_pair_rule_at_the_smallest_length_it_names():
    """The length check's message names passes both check and the collision kernel; one lattice
    spacing less fails both."""
    import re

    from lbmpipe.particles.collisions import CollisionParams, Domain, resolve_collisions
    from lbmpipe.particles.rigid import Bodies
    from lbmpipe.scene import Collisions, Scene, SceneError
    from lbmpipe.particles.shapes import CUBE

    with pytest.raises(SceneError) as err:
        Scene.model_validate(_two_cubes())
    need = float(re.search(r"at least ([0-9.]+) mm", str(err.value)).group(1))
    dx = PAPER_PIPE["numerics"]["dx_mm"]
    c = Collisions()  # the scene's collision settings, passed to the kernel as the run passes them
    prm = CollisionParams(restitution=c.restitution, contact_gap=c.contact_gap_dx, overlap_tol=c.overlap_tol_dx)
    for length, ok in ((need, True), (need - dx, False)):
        data = _with(_two_cubes(), **{"domain.length_mm": length})
        bodies = Bodies.make(CUBE, [8.0 / dx] * 3, 1.0, [[-12.0 / dx, 0.0, 4.0], [12.0 / dx, 0.0, 4.0]])
        dom = Domain.pipe(25.0 / dx, length / dx)
        if ok:
            Scene.model_validate(data)
            resolve_collisions(bodies, dom, prm, dt=1.0)
        else:
            with pytest.raises(SceneError, match="two interaction ranges"):
                Scene.model_validate(data)
            with pytest.raises(SceneError, match="two interaction ranges"):
                resolve_collisions(bodies, dom, prm, dt=1.0)


def test_a_single_free_16mm_cube_in_the_50mm_pipe_runs(tmp_path):
    """Issue 32's "check passes, run crashes" and issue 34's small periodic box: one free body
    meets only the wall, so the pair search's length rule does not apply."""
    one = _with(PAPER_PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 16.0, "position_mm": [0, 0, 25]}]})
    scene = _scene_file(tmp_path, one)
    res = _cli(["run", scene, "--out", tmp_path / "out", "--quiet", "--steps", "4"], cwd=tmp_path, timeout=1800,
               limits=False)  # compiling the cube kernels from a cold cache needs more than the limit
    assert res.returncode == 0, res.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["collisions"]["pairs"] is False


def test_overlap_depth_of_explicit_bodies_matches_the_collision_models_narrow_phase():
    """check's NumPy separating-axis depth against lbmpipe.particles.contact.body_contact (GJK/EPA and the
    exact cylinder path) on random overlapping and separated pairs of every shape."""
    from lbmpipe.particles.contact import body_contact
    from lbmpipe.inputs import half_extents, pair_gap_mm, rotation
    from lbmpipe.particles.rigid import random_quaternions
    from lbmpipe.scene import ParticleBody, Scene
    from lbmpipe.particles.shapes import CUBE, CYLINDER, SPHERE

    scene = Scene.model_validate(_with(PIPE, **{"domain.length_mm": 200.0}))
    kinds = {"sphere": SPHERE, "cylinder": CYLINDER, "cube": CUBE}
    sizes = {"sphere": {"diameter_mm": 4.0}, "cylinder": {"diameter_mm": 4.0, "length_mm": 6.0},
             "cube": {"edge_mm": 4.0}}
    rng = np.random.default_rng(7)
    qs = random_quaternions(120, rng)
    worst = 0.0
    for k in range(60):
        s1, s2 = rng.choice(list(sizes), 2)
        d = rng.normal(size=3)
        d *= rng.uniform(2.0, 7.0) / np.linalg.norm(d)
        b1 = ParticleBody(shape=s1, **sizes[s1], position_mm=(0.0, 0.0, 50.0), orientation=tuple(qs[2 * k]))
        b2 = ParticleBody(shape=s2, **sizes[s2], position_mm=tuple(np.array([0, 0, 50.0]) + d),
                          orientation=tuple(qs[2 * k + 1]))
        ours = pair_gap_mm(scene, b1, b2)
        ref = body_contact(kinds[s1], half_extents(b1), np.zeros(3), rotation(b1.orientation), kinds[s2],
                           half_extents(b2), d, rotation(b2.orientation), 1e9, 0.0, np.zeros(3), np.zeros(3))
        if ours < 0 or ref < 0:  # overlapping: both see it, with the same depth
            assert ours < 0 and ref < 0
            worst = max(worst, abs(ours - ref))
    assert worst < 1e-3  # mm, bodies of 4-6 mm
    print(f"largest depth difference {worst:.2e} mm")


# -- nothing finished is lost ---------------------------------------------------------------------

def test_a_kill_while_writing_the_outputs_keeps_the_checkpoint_and_the_rerun_resumes(tmp_path, monkeypatch):
    from lbmpipe import outputs
    from lbmpipe.scene import Scene
    from lbmpipe.run import run_scene
    from lbmpipe.units import derive

    scene = Scene.model_validate(PIPE)
    params = derive(scene)
    ck, out = tmp_path / "c.npz", tmp_path / "out"
    part = run_scene(scene, params, out, progress=False, checkpoint=ck, stop_at_step=8)
    assert part["status"] == "interrupted" and ck.exists()

    def killed(*a, **k):
        raise KeyboardInterrupt  # the kill arrives after the last step, while the outputs are written

    monkeypatch.setattr(outputs, "write_summary", killed)
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, params, out, progress=False, checkpoint=ck)
    assert ck.exists()  # the final state is not lost: the checkpoint outlives the unwritten outputs
    assert not list(out.glob(".*.tmp"))  # no half-written file left
    monkeypatch.undo()
    done = run_scene(scene, params, out, progress=False, checkpoint=ck)
    assert done["status"] == "completed" and done["checkpoint"]["resumed_from_step"] == 8
    assert not ck.exists() and not done["checkpoint"]["kept"]
    whole = run_scene(scene, params, tmp_path / "whole", progress=False)
    assert (out / "flow_rate.csv").read_bytes() == (tmp_path / "whole" / "flow_rate.csv").read_bytes()
    assert whole["steps"] == done["steps"]


def test_the_scenes_run_threads_sets_numbas_thread_count(tmp_path):
    scene = _scene_file(tmp_path, _with(PIPE, **{"run.threads": 1}))
    res = _cli(["run", scene, "--out", tmp_path / "out", "--quiet", "--steps", "2"], cwd=tmp_path,
               env_extra={"NUMBA_NUM_THREADS": "2"}, timeout=1800)
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["threads"] == 1


def test_snakemake_refuses_a_bad_config_with_one_line_before_any_job(tmp_path):
    if shutil.which("snakemake", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("snakemake not installed beside this interpreter")
    before = _tree(ROOT / "results") if (ROOT / "results").exists() else {}
    res = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "--config", "fidelity=bogus"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode != 0
    lines = [ln for ln in res.stderr.splitlines() if "config error in" in ln]
    assert len(lines) == 1 and "fidelity" in lines[0] and "Fix:" in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert (_tree(ROOT / "results") if (ROOT / "results").exists() else {}) == before


def test_a_target_of_another_level_without_its_fidelity_is_refused_naming_the_fix_and_plans_nothing():
    """The level-wide rules gather the configured level's cases: a table of another level asked for by
    its path alone would plan that level's runs from the wrong list (it did: scene files appeared)."""
    if shutil.which("snakemake", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("snakemake not installed beside this interpreter")
    before = _tree(ROOT / "results")
    res = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "--nolock",
                          "results/credible_dx2/tables/run_health.csv"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "--config fidelity=credible_dx2" in out and "rule simulate_" not in out
    assert _tree(ROOT / "results") == before
    ok = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "--nolock", "--config",
                         "fidelity=credible_dx2", "--", "results/credible_dx2/tables/run_health.csv"], cwd=ROOT,
                        capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]


# -- guard messages name the likeliest cause ----------------------------------------------------

def test_guard_blames_the_wall_film_for_a_failure_at_a_wall_node_not_the_mach_number():
    from lbmpipe.guard import Unstable
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    data = _with(PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 4.0, "position_mm": [5.0, 0, 10]}]},
                 **{"numerics.dx_mm": 1.0, "numerics.dt_s": 4.0e-3, "numerics.mach_limit": 2.0})
    scene = Scene.model_validate(data)
    params = derive(scene)
    assert params.mach_max > 0.35  # the Mach number alone would be blamed
    sim = simulation_from_scene(scene, params)
    x, y, _ = sim.grid.positions()
    r = np.hypot(x[:, None], y[None, :])
    fluid = sim.fluid_mask()[:, :, 10]
    wall = np.argwhere(fluid & (r > sim.grid.radius - 1.0) & (x[:, None] < -3.0))
    ix, iy = map(int, wall[0])
    good = sim.f[:, ix, iy, 10].copy()
    sim.f[:, ix, iy, 10] = np.nan
    with pytest.raises(Unstable) as err:
        sim.guard.check(sim)
    assert "next to the wall" in err.value.cause and "Mach" not in err.value.cause
    assert "contact_gap_dx" in err.value.fix
    sim.f[:, ix, iy, 10] = good
    ixc, iyc = map(int, np.argwhere(fluid & (r < 1.0))[0])
    sim.f[:, ixc, iyc, 10] = np.nan
    with pytest.raises(Unstable) as err:
        sim.guard.check(sim)
    assert "Mach" in err.value.cause  # in the bulk, the high Mach number stays the likeliest cause


def test_guard_names_the_density_floor_when_it_has_added_much_of_the_fluid_mass():
    from lbmpipe.fluid import effects as fx
    from lbmpipe.guard import Unstable
    from lbmpipe.scene import Scene
    from lbmpipe.assemble import simulation_from_scene
    from lbmpipe.units import derive

    data = _with(PIPE, particles={"bodies": [{"shape": "cube", "edge_mm": 5.0, "position_mm": [0, 0, 10]}]})
    scene = Scene.model_validate(data)
    sim = simulation_from_scene(scene, derive(scene))
    sc = sim.effect(fx.StreamCollide)
    sc.tally[0] = 0.5 * sim.guard.mass0  # the floor has added half the fluid mass
    ix, iy, iz = map(int, np.argwhere(sim.fluid_mask())[0])
    sim.f[:, ix, iy, iz] *= 5.0 / sim.f[:, ix, iy, iz].sum()
    with pytest.raises(Unstable) as err:
        sim.guard.check(sim)
    assert "density floor has added 50 % of the fluid mass" in err.value.cause
    assert "contact_gap_dx" in err.value.fix


# -- the hint after an argument error names the command's own help ---------------------------------

@pytest.mark.parametrize("command", ["", "check", "run", "check-config", "stability", "document"])
def test_an_unknown_option_points_to_the_help_of_its_own_command(command, capsys):
    from lbmpipe import cli

    assert set(cli.COMMANDS) <= {"check", "run", "check-config", "stability", "document"}  # every command below
    with pytest.raises(SystemExit) as exc:
        cli.main([*([command] if command else []), "--no-such-option"])
    assert exc.value.code == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("argument error in ") and line.count("\n") == 0, line
    assert line.endswith(f"Fix: see '{' '.join(['lbmpipe', *([command] if command else [])])} --help'"), line


# -- the time estimate of a scene with particles says what it leaves out ------------------------------

def test_check_of_a_scene_with_21_particles_does_not_call_it_particle_free():
    from lbmpipe.cli import format_report
    from lbmpipe.scene import Scene
    from lbmpipe.units import derive

    with_particles = Scene.model_validate(_with(PIPE, particles={"random": [
        {"shape": "sphere", "diameter_mm": 2.5, "count": 20}], "bodies": [
        {"shape": "sphere", "diameter_mm": 2.5, "position_mm": [0, 0, 10]}]}))
    row = next(ln for ln in format_report(with_particles, derive(with_particles)).splitlines()
               if "estimated run time" in ln)
    assert "no particles" not in row and "the 21 particles' coupling and collisions are not counted" in row, row
    flow = Scene.model_validate(PIPE)
    row = next(ln for ln in format_report(flow, derive(flow)).splitlines() if "estimated run time" in ln)
    assert "particle" not in row, row


# -- strict JSON: no NaN or Infinity token in any file the package writes ---------------------------

def _strict_loads(text: str):
    def refuse(token):
        raise ValueError(f"{token} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_strict_json_writes_non_finite_numbers_as_null_and_names_them():
    from lbmpipe.outputs import jsonable, strict_json

    doc = {"a": float("nan"), "b": [1.0, np.float32(np.inf)], "c": {"d": -np.inf, "e": np.int64(3)},
           "f": np.array([0.5, np.nan])}
    bad: list[str] = []
    assert jsonable(doc, bad) == {"a": None, "b": [1.0, None], "c": {"d": None, "e": 3}, "f": [0.5, None]}
    assert bad == ["a", "b[1]", "c.d", "f[1]"]
    assert _strict_loads(strict_json(doc)) == {"a": None, "b": [1.0, None], "c": {"d": None, "e": 3},
                                                "f": [0.5, None]}


def test_an_unstable_run_writes_a_strict_json_summary_and_names_the_values_that_were_not_finite(tmp_path):
    """A heavy sphere under 1e5 m/s^2 toward the wall: the density goes non-finite within a few
    steps and the mass drift with it."""
    heavy = _with(PIPE, particles={"bodies": [{"shape": "sphere", "diameter_mm": 6.0, "position_mm": [0, 0, 10],
                                               "density_ratio": 10.0}], "gravity_m_s2": [1.0e5, 0.0, 0.0]})
    res = _cli(["run", _scene_file(tmp_path, heavy), "--out", tmp_path / "out", "--quiet", "--steps", "40"],
               cwd=tmp_path, timeout=1800, limits=False)
    assert res.returncode == 4, res.stderr
    summary = _strict_loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "unstable" and summary["mass_drift_rel"] is None
    assert "Not finite, written as null in summary.json: mass_drift_rel" in summary["message"]
    assert "mass_drift_rel" in res.stderr  # the run's message says it too


def test_every_committed_json_file_under_results_is_strict_json():
    """summary.json, stats.json and every other JSON file the pipeline committed: no NaN, Infinity."""
    files = sorted((ROOT / "results").rglob("*.json"))
    assert any(f.name == "summary.json" for f in files) and any(f.name == "stats.json" for f in files)
    bad = []
    for f in files:
        try:
            _strict_loads(f.read_text())
        except ValueError as exc:
            bad.append(f"{f.relative_to(ROOT)}: {exc}")
    assert not bad, "\n".join(bad[:20])


# -- the pipeline's config is read as strictly as a scene --------------------------------------------

def test_a_key_that_overrides_a_merged_anchor_is_not_a_key_given_twice():
    """config.yaml's levels copy the credible level (`<<: *credible`) and change one entry."""
    from lbmpipe.errors import SceneError
    from lbmpipe.scene import parse_strict_yaml

    assert parse_strict_yaml("a: &x {p: 1, q: 2}\nb:\n  <<: *x\n  q: 3\n", "f.yaml") == \
        {"a": {"p": 1, "q": 2}, "b": {"p": 1, "q": 3}}
    with pytest.raises(SceneError, match="given twice"):
        parse_strict_yaml("a: &x {p: 1}\nb:\n  <<: *x\n  q: 3\n  q: 4\n", "f.yaml")


def test_check_config_accepts_the_committed_config():
    res = _cli(["check-config", ROOT / "config.yaml", "--root", ROOT], cwd=ROOT)
    assert res.returncode == 0 and "valid" in res.stdout, res.stderr


def test_snakemake_refuses_a_config_file_with_a_key_given_twice_before_any_job(tmp_path):
    if shutil.which("snakemake", path=str(Path(sys.executable).parent)) is None:
        pytest.skip("snakemake not installed beside this interpreter")
    cfg = tmp_path / "config.yaml"
    cfg.write_bytes(_CONFIG_FIDELITY_TWICE)
    before = _tree(ROOT / "results") if (ROOT / "results").exists() else {}
    res = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "--configfile", str(cfg)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode != 0
    lines = [ln for ln in res.stderr.splitlines() if "config error in" in ln]
    assert len(lines) == 1 and "fidelity" in lines[0] and "given twice" in lines[0] and "Fix:" in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert (_tree(ROOT / "results") if (ROOT / "results").exists() else {}) == before


def test_document_refuses_a_config_with_a_key_given_twice(tmp_path, capsys):
    from lbmpipe import cli

    (tmp_path / "results" / "paper").mkdir(parents=True)
    (tmp_path / "config.yaml").write_bytes(_CONFIG_FIDELITY_TWICE)
    with pytest.raises(SystemExit) as exc:
        cli.main(["document", "--fidelity", "paper", "--root", str(tmp_path)])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("config error in fidelity") and "given twice" in lines[0], lines
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["config.yaml", "paper", "results"]  # nothing written
