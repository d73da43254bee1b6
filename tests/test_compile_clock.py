"""A kernel compiled during the time loop (a cold numba cache compiles every kernel at its first
call) is kept out of the effects' timers and of MLUPS, recorded as ``compile_seconds``, and the
progress line says "compiling kernels" while it lasts (issue 46, item 6)."""

import types

import numba
import numpy as np
import yaml

from lbmpipe import run as run_mod
from lbmpipe.compile_clock import CLOCK
from lbmpipe.effect import Effect
from lbmpipe.fluid import boundaries as bnd
from lbmpipe.fluid.lattice import get_lattice
from lbmpipe.scene import Scene
from lbmpipe.solver import Simulation
from lbmpipe.units import derive


def _fresh_kernel():
    """A kernel no cache holds: a new dispatcher, compiled at its first call."""

    @numba.njit
    def kernel(a):
        s = 0.0
        for i in range(a.size):
            s += np.sin(a[i]) * np.cos(a[i]) + np.sqrt(abs(a[i]))
        return s

    return kernel


class Probe(Effect):
    """A post effect whose first call compiles a kernel (what a cold cache does to every effect)."""

    name = "probe"
    phase = "post"

    def __init__(self):
        self.kernel = _fresh_kernel()
        self.data = np.linspace(0.0, 1.0, 16)

    def __call__(self, sim):
        self.kernel(self.data)


def test_a_kernel_compiled_inside_an_effect_is_charged_to_compilation_not_to_the_effect():
    grid = bnd.box_grid(get_lattice("D3Q15"), (4, 4, 4), (False, False, False))
    sim = Simulation.build(grid, collision="bgk", omega=1.0, extra_effects=[Probe()])
    sim.step(1)
    compiled = sim.compile_seconds
    assert compiled > 0.01  # numba compiled the probe's kernel in the first step
    assert sim.timers["probe"] < 0.1 * compiled  # the effect's own time is microseconds
    sim.step(3)
    assert sim.compile_seconds == compiled  # nothing left to compile


def test_progress_line_says_compiling_kernels_while_numba_compiles():
    progress = run_mod.Progress(10, types.SimpleNamespace(dt_s=1e-3), 100, enabled=False)
    shown = []
    progress.bar = types.SimpleNamespace(set_postfix_str=shown.append, update=lambda n: None)
    progress.text = "0.001 s simulated, 2 MLUPS"
    kernel = _fresh_kernel()
    with CLOCK.watch(progress.compiling):
        kernel(np.ones(4))
    assert shown == [run_mod.Progress.COMPILING, "0.001 s simulated, 2 MLUPS"]
    kernel(np.ones(4))  # outside the watch, compiled: nothing shown
    assert len(shown) == 2


def test_run_summary_records_compile_seconds_and_keeps_them_out_of_mlups_and_the_effects(tmp_path, monkeypatch):
    scene = Scene.model_validate(yaml.safe_load((run_mod.Path(__file__).parents[1] / "scenes" / "box_couette.yaml")
                                                .read_text()) | {"run": {"duration_s": 0.02, "spinup_s": 0.01,
                                                                         "sample_interval_s": 0.01}})
    params = derive(scene)
    build = run_mod.simulation_from_scene

    def with_probe(scene, params):
        sim = build(scene, params)
        sim.effects.append(Probe())
        sim.timers["probe"] = 0.0
        return sim

    monkeypatch.setattr(run_mod, "simulation_from_scene", with_probe)
    s = run_mod.run_scene(scene, params, tmp_path / "out", progress=False)
    assert s["status"] == "completed"
    assert s["compile_seconds"] > 0.01 and s["effects"]["probe"] < 0.1 * s["compile_seconds"]
    stepping = s["wall_seconds"] - s["compile_seconds"]
    assert stepping > 0
    assert np.isclose(s["mlups"], s["fluid_nodes"] * s["steps"] / stepping / 1e6)
    assert s["setup_compile_seconds"] >= 0.0
