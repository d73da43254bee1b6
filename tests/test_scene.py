"""Scene validation (lbmpipe.scene): every kind of bad scene names its field and a fix."""

import copy
import math
from pathlib import Path

import pytest
import yaml

from lbmpipe import cli
from lbmpipe.scene import Scene, SceneError, load_scene
from lbmpipe.scene_docs import describe_fields
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"

PIPE = {
    "name": "pipe",
    "domain": {"kind": "pipe", "diameter_mm": 50.0, "length_mm": 100.0},
    "fluid": {"reynolds": 9.4},
    "driving": {"kind": "flow_rate", "flow_rate_m3_s": 1.577e-4},
    "initial": {"velocity": "parabolic"},
    "run": {"duration_s": 1.0, "spinup_s": 0.5},
}
BOX = {
    "name": "box",
    "domain": {"kind": "box", "size_mm": [1.0, 32.0, 1.0], "walls": {"x": "periodic", "y": "wall", "z": "periodic"}},
    "fluid": {"viscosity_m2_s": 1e-4},
    "driving": {"kind": "body_force", "acceleration_m_s2": [0.01, 0.0, 0.0]},
    "run": {"duration_s": 1.0, "spinup_s": 0.5},
}


def edit(base: dict, path: str, value) -> dict:
    """Copy of ``base`` with ``value`` at dotted ``path`` (value ``...`` deletes the key)."""
    data = copy.deepcopy(base)
    *parents, last = path.split(".")
    node = data
    for key in parents:
        node = node.setdefault(key, {})
    if value is ...:
        node.pop(last)
    else:
        node[last] = value
    return data


# (id, scene dict, field named in the error, words the message must contain)
BAD_SCENES = [
    ("unknown_key", edit(PIPE, "colour", "red"), "colour", ["unknown key 'colour'", "valid keys here: name, domain"]),
    ("mistyped_key", edit(PIPE, "numerics.dx_m", 1.0), "numerics.dx_m", ["unknown key 'dx_m'", "did you mean 'dx_mm'"]),
    ("wrong_type", edit(PIPE, "numerics.dt_s", "fast"), "numerics.dt_s", ["valid number", "'fast'"]),
    ("bad_choice", edit(PIPE, "numerics.lattice", "D2Q9"), "numerics.lattice", ["'D2Q9' is not an allowed value", "D3Q15"]),
    ("bad_collision_operator", edit(PIPE, "numerics.collision", "mrt"), "numerics.collision",
     ["'mrt' is not an allowed value", "'bgk' or 'trt'"]),
    # the guard's interval is fixed (guard.DEFAULT_EVERY); a scene cannot set it
    ("guard_interval_not_a_scene_key", edit(PIPE, "numerics.guard_every", 10), "numerics.guard_every",
     ["unknown key 'guard_every'"]),
    ("section_not_mapping", edit(PIPE, "run", 5), "run", ["expected a mapping"]),
    ("missing_required", edit(PIPE, "domain.kind", ...), "domain.kind", ["required field is missing"]),
    ("negative_viscosity", edit(BOX, "fluid.viscosity_m2_s", -1e-4), "fluid.viscosity_m2_s", ["greater than 0"]),
    ("tau_not_above_half", edit(BOX, "fluid.viscosity_m2_s", 1e-20), "numerics.dt_s", ["tau = 0.5 <= 1/2", "increase numerics.dt_s"]),
    ("mach_above_limit", edit(edit(PIPE, "fluid.reynolds", 26.0), "driving.flow_rate_m3_s", 3.154e-4), "numerics.dt_s",
     ["Mach 0.556 exceeds numerics.mach_limit 0.35", "reduce numerics.dt_s to <= 0.000628 s", "raise numerics.mach_limit"]),
    ("pipe_too_coarse", edit(PIPE, "domain.diameter_mm", 5.0), "domain.diameter_mm",
     ["only 5 nodes across", "min_diameter_nodes = 8", "reduce numerics.dx_mm to <= 0.625"]),
    ("box_wall_gap_too_coarse", edit(BOX, "domain.size_mm", [1.0, 4.0, 1.0]), "domain.size_mm[1]", ["only 4 nodes"]),
    ("length_not_multiple_of_dx", edit(PIPE, "domain.length_mm", 100.5), "domain.length_mm",
     ["domain.length_mm = 100.5 is not a multiple of numerics.dx_mm = 1", "use 100 or 101"]),
    ("both_viscosity_and_reynolds", edit(PIPE, "fluid.viscosity_m2_s", 1e-4), "fluid.reynolds",
     ["both fluid.viscosity_m2_s and fluid.reynolds"]),
    ("neither_viscosity_nor_reynolds", edit(BOX, "fluid.viscosity_m2_s", ...), "fluid.viscosity_m2_s", ["neither"]),
    ("reynolds_in_a_box", edit(edit(BOX, "fluid.viscosity_m2_s", ...), "fluid.reynolds", 10.0), "fluid.reynolds",
     ["only for a pipe with driving.kind: flow_rate"]),
    ("flow_rate_with_box", edit(BOX, "driving", {"kind": "flow_rate", "flow_rate_m3_s": 1e-6}), "driving.kind",
     ["flow_rate driving is defined for a pipe only"]),
    ("flow_rate_without_rate", edit(PIPE, "driving.flow_rate_m3_s", ...), "driving.flow_rate_m3_s", ["no flow rate is given"]),
    ("body_force_without_acceleration", edit(BOX, "driving.acceleration_m_s2", [0, 0, 0]), "driving.acceleration_m_s2",
     ["needs a non-zero acceleration"]),
    ("transverse_force_in_pipe", edit(edit(edit(PIPE, "fluid", {"viscosity_m2_s": 4e-4}), "driving", {"kind": "body_force", "acceleration_m_s2": [0.1, 0, 0]}), "initial.velocity", "rest"),
     "driving.acceleration_m_s2", ["transverse acceleration drives no flow"]),
    ("moving_wall_on_periodic_axis", edit(BOX, "domain.moving_walls", [{"side": "x+", "velocity_m_s": [0, 0.01, 0]}]),
     "domain.moving_walls[0].side", ["axis x, which is periodic", "domain.walls.x: wall"]),
    ("moving_wall_not_tangential", edit(BOX, "domain.moving_walls", [{"side": "y+", "velocity_m_s": [0.01, 0.002, 0]}]),
     "domain.moving_walls[0].velocity_m_s", ["must slide tangentially"]),
    ("walls_on_a_pipe", edit(PIPE, "domain.walls", {"x": "wall"}), "domain.walls", ["walls is for a box"]),
    ("parabolic_in_a_box", edit(BOX, "initial", {"velocity": "parabolic"}), "initial.velocity", ["driven pipe only"]),
    ("spinup_not_before_end", edit(PIPE, "run", {"duration_s": 2.0, "spinup_s": 2.0}), "run.spinup_s",
     ["spin-up 2 s is not shorter than run.duration_s = 2 s"]),
    ("sample_interval_beyond_run", edit(PIPE, "run.sample_interval_s", 5.0), "run.sample_interval_s", ["longer than run.duration_s"]),
    ("bad_name", edit(PIPE, "name", "my scene/1"), "name", ["pattern"]),
]


def _error_of(data: dict) -> SceneError:
    with pytest.raises(SceneError) as info:
        derive(Scene.model_validate(data))
    return info.value


@pytest.mark.parametrize("data, field, words", [c[1:] for c in BAD_SCENES], ids=[c[0] for c in BAD_SCENES])
def test_bad_scene_error_names_field_and_fix(data, field, words):
    err = _error_of(data)
    matching = [e for e in err.errors if e.field == field]
    assert matching, f"no error for {field}: {err}"
    line = matching[0].line()
    assert line.startswith(f"scene error in {field}: ")
    assert ". Fix: " in line and matching[0].fix
    for word in words:
        assert word in line


@pytest.mark.parametrize("data, field", [c[1:3] for c in BAD_SCENES], ids=[c[0] for c in BAD_SCENES])
def test_bad_scene_makes_cli_check_exit_2(data, field, tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(SystemExit) as info:
        cli.main(["check", str(path)])
    assert info.value.code == 2
    assert f"scene error in {field}" in capsys.readouterr().err


def test_good_base_scenes_are_accepted():
    for base in (PIPE, BOX):
        derive(Scene.model_validate(base))


def test_all_problems_are_listed_at_once():
    data = edit(edit(PIPE, "numerics.dxmm", 1.0), "run.spinup", 1.0)
    err = _error_of(data)
    assert {e.field for e in err.errors} == {"numerics.dxmm", "run.spinup"}
    assert str(err).count("scene error in") == 2
    data = edit(edit(PIPE, "domain.length_mm", 100.5), "fluid.viscosity_m2_s", 1e-4)
    assert {e.field for e in _error_of(data).errors} == {"domain.length_mm", "fluid.reynolds"}


def test_scene_error_string_format():
    err = SceneError("numerics.dt_s", "tau = 0.49 <= 1/2", "increase dt_s")
    assert str(err) == "scene error in numerics.dt_s: tau = 0.49 <= 1/2. Fix: increase dt_s"
    assert isinstance(err, ValueError)


def test_yaml_key_given_twice_is_an_error(tmp_path):
    path = tmp_path / "dup.yaml"
    path.write_text(yaml.safe_dump(PIPE) + "name: other\n")
    with pytest.raises(SceneError, match="given twice"):
        load_scene(path)


def test_missing_file_and_non_mapping_are_scene_errors(tmp_path):
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "nope.yaml")
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(SceneError, match="YAML mapping"):
        load_scene(tmp_path / "list.yaml")


def test_contract_example_fields_validate():
    # The example of helper_notes/scene_api.md, pipe part (box-only keys dropped).
    text = """
name: pipe_re9.4
domain: {kind: pipe, diameter_mm: 50.0, length_mm: 100.0}
fluid: {density_kg_m3: 1000.0, viscosity_m2_s: null, reynolds: 9.4}
driving: {kind: flow_rate, flow_rate_m3_s: 1.577e-4, acceleration_m_s2: [0, 0, 0]}
initial: {velocity: parabolic}
numerics: {dx_mm: 1.0, dt_s: 1.0e-3, lattice: D3Q15, collision: bgk, trt_magic: 0.1875, wall: bounce_back,
           precision: float64, mach_limit: 0.35, min_diameter_nodes: 8}
run: {duration_s: 10.0, spinup_s: 2.0, sample_interval_s: 0.05, threads: null}
outputs: {profile: true, flow_rate: true}
"""
    scene = Scene.model_validate(yaml.safe_load(text))
    assert scene.driving.flow_rate_m3_s == 1.577e-4 and scene.numerics.lattice == "D3Q15"


@pytest.mark.parametrize("path", sorted(SCENES.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_scenes_validate(path):
    scene = load_scene(path)
    params = derive(scene)
    assert params.tau > 0.5 and params.mach_max <= scene.numerics.mach_limit
    assert params.spinup_steps < params.n_steps


@pytest.mark.parametrize("name, q, re_", [("pipe_re9.4", 1.577e-4, 9.4), ("pipe_re26", 3.154e-4, 26.0)])
def test_pipe_scenes_use_the_papers_parameters(name, q, re_):
    s = load_scene(SCENES / f"{name}.yaml")
    assert (s.domain.kind, s.domain.diameter_mm, s.domain.length_mm) == ("pipe", 50.0, 100.0)
    assert (s.numerics.dx_mm, s.numerics.dt_s, s.numerics.lattice, s.numerics.collision, s.numerics.wall) == (
        1.0, 1e-3, "D3Q15", "bgk", "bounce_back")
    assert (s.driving.kind, s.driving.flow_rate_m3_s, s.fluid.reynolds, s.initial.velocity) == ("flow_rate", q, re_, "parabolic")


def test_validation_scenes_reach_steady_state_within_spinup():
    # The slowest plane-channel mode decays with time constant H^2 / (pi^2 nu).
    for name in ("box_couette", "box_poiseuille"):
        s = load_scene(SCENES / f"{name}.yaml")
        h = s.domain.size_mm[1] * 1e-3
        assert s.run.spinup_s > 5 * h**2 / (math.pi**2 * s.fluid.viscosity_m2_s)


def test_docs_scene_md_is_generated_from_the_models():
    docs = (ROOT / "docs" / "scene.md").read_text()
    assert docs == describe_fields(), "regenerate docs/scene.md with lbmpipe.scene_docs.describe_fields()"
    for model in (Scene,) + tuple(type(getattr(Scene.model_validate(PIPE), k)) for k in
                                  ("domain", "fluid", "driving", "initial", "numerics", "run", "outputs")):
        for field, info in model.model_fields.items():
            assert f"| `{field}` |" in docs
            assert info.description, f"{model.__name__}.{field} has no description"
