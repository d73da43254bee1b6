"""README.md tells the truth about the committed results: each figure it quotes is recomputed here
from the files it names (results/credible/claims.csv, tables/*.csv, the cases' stats.json, the
packing records), every other number in its prose is a parameter of config.yaml or of the paper's
pipe, and the commands it shows work (the rerun order, the report's path, the test command CI runs).
Numbers inside code spans and blocks are program text (commands, paths, case names), not results."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from lbmpipe.reproduction.pipe import PIPE
from lbmpipe.reproduction.profile_error import read_profile_error

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
LEVEL = ROOT / "results" / "credible"
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text())


def _flat(text: str) -> str:
    return " ".join(text.split())


def _prose(text: str) -> str:
    """The README without code blocks, code spans and link targets."""
    text = re.sub(r"```.*?```", " ", text, flags=re.S)
    text = re.sub(r"`[^`]*`", " ", text)
    return re.sub(r"\]\([^)]*\)", "]", text)


def _numbers(text: str) -> list[str]:
    return re.findall(r"(?<![\w.^])(\d+(?:\.\d+)?)(?![\w])", text)


def _g(x: float, sig: int) -> str:
    return f"{x:.{sig}g}"


def _claims() -> pd.DataFrame:
    return pd.read_csv(LEVEL / "claims.csv")


def _listed(claims: pd.DataFrame, column: str, value: str) -> list[int]:
    return sorted(int(c) for c in claims.loc[claims[column] == value, "claim"])


def _facts() -> dict[str, str]:
    """Each quoted phrase of the README, rebuilt from the committed file it comes from."""
    facts = {}
    claims = _claims()
    rep, con, inc = (_listed(claims, "verdict", v) for v in ("reproduced", "contradicted", "inconclusive"))
    ids = lambda xs: ", ".join(map(str, xs))  # noqa: E731
    facts["claims.csv verdicts"] = (f"Of the paper's {len(claims)} claims, {len(rep)} reproduced ({ids(rep)}), "
                                    f"{len(con)} contradicted ({ids(con)[:2]}")
    facts["claims.csv inconclusive"] = f"{len(inc)} inconclusive ({ids(inc)})"
    clean = _listed(claims, "verdict_without_flagged", "reproduced")
    facts["verdict_without_flagged"] = (f"without the flagged cases only claim {ids(clean)} is reproduced"
                                        if len(clean) == 1 else
                                        f"without the flagged cases only claims {ids(clean[:-1])} and {clean[-1]} "
                                        "are reproduced")
    differ = _listed(claims, "same_under_both_methods", "no")
    facts["same_under_both_methods"] = f"claims {' and '.join(map(str, differ))} change with the method"
    # the contradicted claim is the cube-cylinder comparison the README names
    assert "Cubes rotate faster than cylinders" in claims.set_index("claim").loc[con[0], "statement"]

    av = pd.read_csv(LEVEL / "tables" / "angular_velocity.csv")
    ran = av[~av["status"].isin(["not run", "unpackable"])]
    flags = ran["flags"].fillna("")
    assert (flags != "").all(), "a particle case with results has no flag: the README says all do"
    steady = int(flags.str.contains("not steady").sum())
    facts["flagged cases"] = (f"All {len(ran)} particle cases with results carry a flag "
                              f"(`tables/angular_velocity.csv`, `flags`; \"not steady\" in all {steady})")
    assert steady == len(ran)

    w = av.set_index("case")[["omega_x", "omega_y", "omega_z"]].mean(axis=1)
    ratios = [w[f"cyl{s}x{s}_c{c}_re{re}"] / w[f"cube{s}_c{c}_re{re}"]
              for s in (8, 16) for c in (30, 50) for re in ("9.4", "26")]
    facts["cylinder/cube spin"] = (f"Cylinders spin {_g(min(ratios), 2)}-{_g(max(ratios), 2)} times faster than "
                                   "cubes of the same size (mean |Ω| over the three axes, 8 and 16 mm)")
    osum = pd.read_csv(LEVEL / "tables" / "orientation_summary.csv")
    cyl = osum[(osum["kind"] == "cyl_axis_angle") & osum["collisions"] & osum["concentration"].isin([0.3, 0.5])]
    angle = cyl["mean_deg"].dropna()
    facts["cylinder angles"] = (f"mean angles of {_g(angle.min(), 3)}-{_g(angle.max(), 3)} deg to the pipe axis "
                                f"({_g(math.degrees(1.0), 3)} deg for random orientations")  # mean of sin-weighted angle: 1 rad

    cube24 = ran[ran["case"].str.startswith("cube24_")]
    assert len(cube24) and cube24["flags"].str.contains("locked").all()  # "24 mm cubes lock"
    sd = av[["seed_sd_x", "seed_sd_y", "seed_sd_z"]].to_numpy(float)
    need = [max(json.loads(p.read_text()).get("seeds_for_5pct", {}).values() or [0])
            for p in (LEVEL / "cases").glob("*/stats.json")]
    facts["packing scatter"] = (f"scatter by up to {_g(100 * pd.Series(sd.ravel()).max(), 3)} % (`seed_sd_*` in "
                                f"`tables/angular_velocity.csv`), so a 5 % interval would need up to {max(need)} "
                                "packings (`seeds_for_5pct`")
    assert "seeds_for_5pct" in json.loads((LEVEL / "cases" / "cube8_c30_re9.4" / "stats.json").read_text())

    err = {re_: read_profile_error(LEVEL / "cases" / f"flow_re{re_}" / "profile.csv") for re_ in ("9.4", "26")}
    facts["Hagen-Poiseuille"] = (f"within {_g(100 * err['9.4'], 2)} % (Re 9.4) and {_g(100 * err['26'], 2)} % "
                                 "(Re 26) of Hagen-Poiseuille")
    rt = pd.read_csv(LEVEL / "tables" / "runtime.csv")
    n = rt["status"].value_counts()
    facts["runs"] = (f"{n.get('completed', 0)} runs completed, {n.get('unstable', 0)} ended unstable"
                     + (f", {n.get('not run')} are not run (the dilute reference of claim 14)" if n.get("not run") else ""))
    assert set(rt.loc[rt["status"] == "not run", "case"].str.split("/").str[0]) <= {"cyl8x16_c2_re9.4"}
    facts["time"] = (f"took {_g(rt['wall_s'].sum() / 3600, 3)} core-hours as measured (`wall_s` summed over "
                     f"`results/credible/tables/runtime.csv`), the longest {round(rt['wall_s'].max() / 60)} minutes")

    attempt = json.loads((ROOT / "results" / "packings" / "cube24_c50_s1.json").read_text())
    assert attempt["status"] == "unpackable"
    facts["packing attempt"] = (f"At 50 % the 24 mm cubes are {attempt['count']} bodies; the packer's committed "
                                f"attempt ([results/packings/cube24_c50_s1.json](results/packings/cube24_c50_s1.json)) "
                                f"reached {_g(100 * attempt['concentration_reached'], 3)} % without overlap")
    return facts


def _parameters() -> set[str]:
    """Numbers the README may give as parameters: the paper's pipe, and config.yaml's cases and levels."""
    vals = {PIPE["diameter_mm"], PIPE["length_mm"]}
    for case in CONFIG["cases"].values():
        vals.add(case["reynolds"])
        p = case.get("particles") or {}
        vals.update(p[k] for k in ("diameter_mm", "length_mm", "edge_mm") if k in p)
        if "concentration" in p:
            vals.add(round(100 * p["concentration"]))
    vals.update(f["dx_mm"] for f in CONFIG["fidelities"].values() if "dx_mm" in f)
    out = set()
    for v in vals:
        out.update({f"{v:g}", str(v)})
    return out


def test_readme_quotes_the_committed_results_and_every_other_number_is_a_parameter():
    text = _flat(README)
    facts = _facts()
    missing = {k: v for k, v in facts.items() if _flat(v) not in text}
    assert not missing, missing
    allowed = _parameters() | {x for v in facts.values() for x in _numbers(_prose(v))}
    claims = {str(c) for c in _claims()["claim"]}
    # "claim 14", "claims 11 and 12", "(7: ..." name claims by number
    stray = [x for x in _numbers(_prose(README)) if x not in allowed and x not in claims]
    assert not stray, f"numbers in README.md that no committed file or parameter gives: {stray}"


def test_readme_is_short_and_says_nothing_the_data_contradict():
    assert len(README.splitlines()) <= 250
    text = _flat(README)
    for stale in ("being finished in parts", "34 %", "185 packings", "results/paper/figures",
                  "results/paper/claims.csv", "snakemake --report report.html"):
        assert stale not in text, stale
    image = re.search(r"!\[[^\]]*\]\(([^)]+)\)", README).group(1)
    assert image.startswith("results/credible/figures/") and (ROOT / image).is_file()


def test_readme_says_how_to_switch_field_output_on_with_the_scene_field_docs_describe():
    text = _flat(README)
    assert "outputs: {fields: {interval_s:" in text
    scene_doc = (ROOT / "docs" / "scene.md").read_text()
    assert "Key: `outputs.fields`" in scene_doc and "| `interval_s` |" in scene_doc


def _test_command(text: str) -> str:
    return next(ln for ln in text.splitlines() if "requirements-test.lock" in ln and "pytest" in ln).strip()


def test_ci_runs_the_readme_test_command():
    readme = _test_command(README)
    setup, _, run = readme.partition(" && .venv/bin/python -m pytest")
    ci = (ROOT / ".ci" / "run").read_text()
    assert setup.replace("python3.11", '"$PY"') in ci
    assert re.search(r"^\S*\s*\.venv/bin/python -m pytest" + re.escape(run), ci, flags=re.M), ci


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="needs the git repository")
def test_the_report_path_the_readme_gives_is_ignored_by_git():
    path = re.search(r"snakemake --report (\S+)", README).group(1)
    assert path.startswith("results/")
    assert subprocess.run(["git", "check-ignore", "-q", path], cwd=ROOT).returncode == 0


def _snakemake() -> str:
    return shutil.which("snakemake", path=str(Path(sys.executable).parent)) or "snakemake"


def test_the_readme_rerun_commands_plan_their_run_and_the_other_order_fails():
    block = re.search(r"\*\*Rerunning one run\.\*\*.*?```bash\n(.*?)```", README, flags=re.S).group(1)
    commands = [ln.split() for ln in block.splitlines() if ln.startswith("snakemake")]
    assert len(commands) == 2
    for cmd in commands:
        run = subprocess.run([_snakemake(), "-n", "--nolock", *cmd[1:]], cwd=ROOT, capture_output=True, text=True,
                             timeout=300)
        assert run.returncode == 0, run.stderr[-2000:]
        assert "simulate_particles" in run.stdout + run.stderr, cmd
    # the target after --config, without `--`: what the README warns against
    first = commands[0]
    target = next(w for w in first if w.startswith("results/"))
    wrong = [w for w in first[1:] if w != target] + [target]
    run = subprocess.run([_snakemake(), "-n", "--nolock", *wrong], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode != 0 and "name=value" in run.stdout + run.stderr
