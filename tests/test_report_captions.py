"""The Snakemake report's captions (workflow/report/*.rst) render as Snakemake renders them (Jinja2,
then docutils) without any docutils warning or error, and a report built from a level's outputs
holds no docutils message."""

from __future__ import annotations

import importlib.util
import io
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import jinja2
import pytest
import yaml
from docutils.core import publish_parts

ROOT = Path(__file__).resolve().parent.parent
CAPTIONS = sorted((ROOT / "workflow" / "report").glob("*.rst"))


def _checker():
    spec = importlib.util.spec_from_file_location("check_report", ROOT / "workflow" / "scripts" / "check_report.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def render_caption(text: str) -> tuple[str, str]:
    """(HTML body, docutils warnings) of a caption, rendered as Snakemake's report does."""
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    stub = SimpleNamespace(config=config, wildcards=SimpleNamespace(fidelity="smoke"))
    text = jinja2.Environment(undefined=jinja2.StrictUndefined).from_string(text).render(
        snakemake=stub, categories={}, files={})
    stream = io.StringIO()
    body = publish_parts(text, writer="html",
                         settings_overrides={"warning_stream": stream, "report_level": 2, "halt_level": 5})["body"]
    return body, stream.getvalue()


def test_there_are_captions_for_the_report():
    assert len(CAPTIONS) >= 10


@pytest.mark.parametrize("path", CAPTIONS, ids=lambda p: p.name)
def test_caption_renders_without_docutils_messages(path):
    body, warnings = render_caption(path.read_text())
    assert warnings == "", f"{path.name}: {warnings}"
    assert _checker().docutils_problems(body) == []


def test_an_absolute_value_bar_left_unescaped_is_caught():
    """|Omega| is a substitution reference in reStructuredText: the check must see it fail."""
    body, warnings = render_caption("Mean |Ω| about x, y, z (rad/s).")
    assert "Undefined substitution" in warnings
    assert _checker().docutils_problems(body)
    body, warnings = render_caption(r"Mean \|Ω\| about x, y, z (rad/s).")
    assert warnings == "" and "|Ω|" in body


def test_report_check_flags_docutils_messages_in_a_report():
    check = _checker()
    bad = '<div class="system-message"><p class="system-message-title">System Message: ERROR/3</p></div>'
    assert len(check.docutils_problems(bad)) >= 1
    assert check.docutils_problems('"caption": "<p>Mean |Ω| about x</p>"') == []


def test_report_of_a_built_level_holds_no_docutils_message(tmp_path):
    """The smoke level when it has been built (CI builds it, then checks its report in .ci/run too),
    else the committed paper level: the report is built from the outputs on disk, nothing reruns."""
    level = "smoke" if (ROOT / "results" / "smoke" / "claims.csv").exists() else "paper"
    if not (ROOT / "results" / level / "claims.csv").exists():
        pytest.skip(f"no built level to report on (results/{level}/claims.csv missing)")
    snakemake = shutil.which("snakemake", path=str(Path(sys.executable).parent)) or shutil.which("snakemake")
    out = tmp_path / "report.html"
    run = subprocess.run([snakemake, "--nolock", "--report", str(out), "--config", f"fidelity={level}"], cwd=ROOT,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    assert _checker().docutils_problems(out.read_text(encoding="utf-8", errors="replace")) == []
