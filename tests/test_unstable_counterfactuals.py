"""The counterfactuals of the diagnosis of the unstable runs (`benchmarks/_unstable_probe.py`,
benchmarks/README.md "Issue 47: the two unstable runs"): they change exactly one thing.

`ForceCap` holds the flow-rate controller's driving force at a cap (and its integral with it, so
that the controller does not wind up and recovers at once when the flow returns); below the cap
the controller acts unchanged. `LubricationOff` makes the lubrication effect do nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from _unstable_probe import ForceCap, LubricationOff  # noqa: E402

from lbmpipe.fluid.effects import FlowRateControl  # noqa: E402

Q, R, NU, NZ = 50.0, 20.0, 0.05, 40


def _drive(effect, flux_ratio: float, steps: int):
    """The controller (or its wrapper) stepped with the flux held at ``flux_ratio`` of its target:
    a packing that blocks the pipe (flux low) or a free flow (flux at the target)."""
    sim = SimpleNamespace(force=np.zeros(3), last_flux=flux_ratio * Q * NZ)
    out = []
    for _ in range(steps):
        effect(sim)
        out.append(sim.force[2])
    return np.array(out)


def test_a_blocked_pipe_drives_the_controller_force_up_without_bound_but_the_cap_holds_it():
    free = FlowRateControl(Q, R, NU, NZ)
    f = _drive(free, 0.5, 2000)
    assert f[-1] > 5.0 * free.f_ref  # the controller's integral keeps rising while the flux is short

    ctl = FlowRateControl(Q, R, NU, NZ)
    cap = ForceCap(ctl, 2.0)
    g = _drive(cap, 0.5, 2000)
    assert g.max() <= 2.0 * ctl.f_ref * (1 + 1e-12)
    assert ctl.f_int <= 2.0 * ctl.f_ref * (1 + 1e-12)  # no wind-up behind the cap
    assert cap.capped_steps > 1900
    assert cap.name == ctl.name and cap.phase == ctl.phase  # the step sees the same effect


def test_below_the_cap_the_controller_acts_unchanged():
    a, b = FlowRateControl(Q, R, NU, NZ), FlowRateControl(Q, R, NU, NZ)
    fa = _drive(a, 0.99, 300)
    fb = _drive(ForceCap(b, 100.0), 0.99, 300)
    assert np.array_equal(fa, fb)


def test_lubrication_off_puts_no_film_force_and_leaves_the_bodies_alone():
    calls = []
    lub = SimpleNamespace(name="particles: lubrication (implicit pair impulses)", phase="post", record_key="lubrication",
                          force=np.ones((3, 3)), torque=np.ones((3, 3)), counts=np.array([4, 1]),
                          __call__=lambda sim: calls.append(sim))
    off = LubricationOff(lub)
    off(SimpleNamespace())
    assert not calls and not lub.force.any() and not lub.torque.any() and not lub.counts.any()
    assert off.name == lub.name and off.record_key == "lubrication"
