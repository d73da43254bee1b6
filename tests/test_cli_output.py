"""What `lbmpipe` prints: a plain-text `--help` naming every command, the closing summary of
`lbmpipe run`, and a progress bar whose simulated time is that of the step count it shows."""

import io
import re
import sys
import types
from pathlib import Path

import pytest

from lbmpipe import cli, outputs

ROOT = Path(__file__).resolve().parents[1]
COUETTE = ROOT / "scenes" / "box_couette.yaml"


def _help(capsys) -> str:
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    return capsys.readouterr().out


def test_help_names_every_command_in_plain_text(capsys):
    text = _help(capsys)
    sub = next(a for a in cli.build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    assert set(sub.choices) == {"check", "check-config", "run", "stability", "document"}
    for name in sub.choices:
        assert re.search(rf"^  {name}\b", text, re.M), f"`lbmpipe --help` does not name `{name}`"
    assert "``" not in text and ":func:" not in text  # no reStructuredText markup


SUMMARY = {"status": "completed", "steps": 2000, "steps_requested": 2000, "simulated_seconds": 2.0,
           "wall_seconds": 75.2, "setup_seconds": 4.1, "mlups": 42.3, "threads": 1,
           "files": ["flow_rate.csv", "particles.parquet", "particles_static.csv", "profile.csv"]}


def test_closing_summary_states_status_steps_wall_time_mlups_and_outputs():
    text = cli.format_closing_summary(SUMMARY, Path("runs/re9.4"))
    assert text.splitlines()[0] == "run completed: 2,000 of 2,000 steps, 2 s simulated"
    assert "wall time 75 s stepping + 4 s set-up, 42.3 MLUPS on 1 thread" in text
    assert "outputs in runs/re9.4: summary.json, flow_rate.csv, particles.parquet" in text


def test_closing_summary_of_an_interrupted_run_says_how_far_it_got():
    text = cli.format_closing_summary(dict(SUMMARY, status="interrupted", steps=700, simulated_seconds=0.7), "out")
    assert text.startswith("run interrupted: 700 of 2,000 steps, 0.7 s simulated")


@pytest.fixture
def fake_solver(monkeypatch):
    module = types.ModuleType("lbmpipe.run")
    module.run_scene = lambda scene, params, out_dir, progress, max_steps: dict(SUMMARY, steps_requested=2000)
    monkeypatch.setitem(sys.modules, "lbmpipe.run", module)
    return module


def test_run_ends_with_the_closing_summary_unless_quiet(tmp_path, fake_solver, capsys):
    assert cli.run_cli(["run", str(COUETTE), "--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out.rstrip().splitlines()
    assert out[-3].startswith("run completed: 2,000 of 2,000 steps") and out[-1].startswith(f"  outputs in {tmp_path / 'a'}")
    assert cli.run_cli(["run", str(COUETTE), "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert capsys.readouterr().out == ""


def _draws(bar_output: str) -> list[tuple[int, str]]:
    """(step count, simulated time) of every redraw of the bar."""
    return [(int(m.group(1)), m.group(2)) for m in re.finditer(r"(\d+)/\d+ \[[^\]]*?t=([\d.]+) s", bar_output)]


def test_progress_bar_time_is_the_time_of_the_step_count_it_shows():
    """The run loop sets the postfix at samples only; tqdm redraws the count in between."""
    stream = io.StringIO()
    dt = 0.5e-3  # Re 26: the paper's dt halved
    bar = outputs.progress_bar(1000, dt, 10, file=stream, mininterval=0, miniters=1)  # draw at every update
    bar.update(100)
    bar.set_postfix_str(outputs.progress_text(100, dt, 10, 1.0))
    bar.update(37)  # between two samples
    bar.update(863)
    bar.close()
    draws = _draws(stream.getvalue())
    assert (137, f"{137 * dt:.3f}") in draws and (1000, f"{1000 * dt:.3f}") in draws
    assert all(t == f"{n * dt:.3f}" for n, t in draws)
    assert "MLUPS" in stream.getvalue().split("137/1000")[1].split("\r")[0]  # the sample's MLUPS is kept
