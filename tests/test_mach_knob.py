"""The Mach knob of the pipeline (a level's ``mach_factor``, lbmpipe.reproduction.cases): the same
physical cases at a lower lattice Mach number, dt reduced at fixed dx."""

import copy
from pathlib import Path

import pytest

from lbmpipe.reproduction import cases, study_plan
from lbmpipe.scene import Scene
from lbmpipe.units import derive

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = ROOT / cases.CONFIG_SCHEMA
LEVEL = {"dx_mm": 5.0, "dt_per_mm_s": 1.0e-3, "re26_dt_factor": 0.5, "mach_limit": 0.6,
         "run": {"duration_s": 0.2, "spinup_s": 0.05, "sample_interval_s": 0.05}}
CUBE8 = {"reynolds": 9.4, "particles": {"shape": "cube", "edge_mm": 8, "concentration": 0.30}}
CASES = {"flow_re9.4": {"reynolds": 9.4}, "flow_re26": {"reynolds": 26}, "cube8_c30_re26": {**CUBE8, "reynolds": 26}}


def _derived(name, level):
    scene = Scene.model_validate(cases.case_scene(name, CASES[name], "lvl", level))
    return scene, derive(scene)


@pytest.mark.parametrize("name", ["flow_re9.4", "flow_re26", "cube8_c30_re26"])
def test_mach_factor_one_half_halves_dt_tau_minus_half_and_the_centre_line_mach_number_of_the_same_flow(name):
    s1, p1 = _derived(name, LEVEL)
    s2, p2 = _derived(name, {**LEVEL, "mach_factor": 0.5})
    assert s2.numerics.dt_s == pytest.approx(0.5 * s1.numerics.dt_s, rel=1e-15)  # Re 26: after re26_dt_factor
    assert s2.numerics.dx_mm == s1.numerics.dx_mm
    # the same physical case: viscosity, flow rate, Reynolds number, run length and sampling
    assert s2.fluid == s1.fluid and s2.driving == s1.driving and s2.particles == s1.particles
    nu = [p.nu_lu * p.units.dx_m**2 / p.units.dt_s for p in (p1, p2)]  # m^2/s
    assert nu[1] == pytest.approx(nu[0], rel=1e-12)
    assert p2.reynolds == pytest.approx(p1.reynolds, rel=1e-12)
    assert p2.n_steps == 2 * p1.n_steps and p2.sample_every == 2 * p1.sample_every
    assert p2.spinup_steps == 2 * p1.spinup_steps
    # the lattice: tau - 1/2 and every lattice velocity halved
    assert p2.tau - 0.5 == pytest.approx(0.5 * (p1.tau - 0.5), rel=1e-12)
    assert p2.mach_max == pytest.approx(0.5 * p1.mach_max, rel=1e-12)
    assert p2.u_mean_lu == pytest.approx(0.5 * p1.u_mean_lu, rel=1e-12)
    assert not [w for w in p2.warnings if "multiple of dt" in w]  # run times stay whole steps


def test_a_level_without_mach_factor_writes_the_scenes_it_wrote_before():
    for name, case in CASES.items():
        assert cases.case_scene(name, case, "lvl", LEVEL) == cases.case_scene(name, case, "lvl", {**LEVEL, "mach_factor": 1})
    assert "mach_factor" not in str(cases.case_scene("flow_re9.4", CASES["flow_re9.4"], "lvl", LEVEL))


def test_mach_factor_is_checked_by_the_schema_and_against_whole_step_run_times_naming_the_key():
    config = {"fidelity": "lvl", "fidelities": {"lvl": {**LEVEL, "mach_factor": 0.5}}, "cases": CASES}
    assert cases.config_problems(config, SCHEMA) == []
    for bad in (0, -0.5, 1.5, "half"):
        c = copy.deepcopy(config)
        c["fidelities"]["lvl"]["mach_factor"] = bad
        problems = cases.config_problems(c, SCHEMA)
        assert problems and problems[0].startswith("config error in fidelities.lvl.mach_factor"), problems
        assert "Fix:" in problems[0]
    # 0.3: dt = 1.5 ms at Re 9.4, the 50 ms sample interval is 33.3 steps
    c = copy.deepcopy(config)
    c["fidelities"]["lvl"]["mach_factor"] = 0.3
    problems = cases.config_problems(c, SCHEMA)
    assert len(problems) == 1 and problems[0].startswith("config error in fidelities.lvl.mach_factor: 0.3")
    assert "not a whole number" in problems[0] and "Fix:" in problems[0]


def test_the_study_of_a_level_with_mach_factor_starts_from_its_time_step():
    config = {"study": {}, "fidelities": {"a": LEVEL, "b": {**LEVEL, "mach_factor": 0.5}}}
    a, b = study_plan.study_settings(config, "a"), study_plan.study_settings(config, "b")
    assert b["dt_per_mm_s"] == pytest.approx(0.5 * a["dt_per_mm_s"], rel=1e-15)
