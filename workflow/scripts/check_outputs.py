"""CI check: every case output, table, figure, the claims and the document of a fidelity level
exist, and the tables cover every case of the config.

    python workflow/scripts/check_outputs.py <fidelity>
"""

import json
import sys
from pathlib import Path

import pandas as pd
import yaml

FIGURES = ["fig4_cylinders_re26", "fig5_cubes8_concentration", "fig6_cubes24_reynolds", "fig7a_shape_re9.4",
           "fig7b_shape_re26", "fig8_cylinder_orientation", "fig9_cube_orientation", "fig10_profiles"]
TABLES = ["angular_velocity", "orientation", "orientation_summary", "packing", "run_health", "runtime"]

fidelity = sys.argv[1]
config = yaml.safe_load(Path("config.yaml").read_text())
root = Path("results") / fidelity
cases = config["cases"]
particle_cases = [c for c, cfg in cases.items() if cfg.get("particles") is not None]
# a case declared unpackable has no run and no files of its own: the case tables list it as unpackable
unpackable = {c for c, cfg in cases.items() if cfg.get("unpackable")}
problems = []


def need(path: Path) -> bool:
    if not path.exists():
        problems.append(f"missing {path}")
        return False
    return True


for case, cfg in cases.items():
    if case in unpackable:
        continue
    d = root / "cases" / case
    names = ["summary.json", "flow_rate.csv", "profile.csv"]
    if cfg.get("particles") is not None:
        names += ["particles.parquet", "particles_static.csv", "stats.json", "orientation.csv"]
    for name in names:
        need(d / name)
    if (d / "summary.json").exists():
        status = json.loads((d / "summary.json").read_text())["status"]
        if status not in ("completed", "unpackable"):
            problems.append(f"{case}: status {status}")
for case in particle_cases:
    need(root / "figures" / f"fig3_{case}.png")
for fig in FIGURES:
    for ext in ("pdf", "png"):
        need(root / "figures" / f"{fig}.{ext}")
for table in TABLES:
    if need(root / "tables" / f"{table}.csv"):
        df = pd.read_csv(root / "tables" / f"{table}.csv")
        expected = set(particle_cases) if table not in ("runtime", "run_health") else set(cases) - unpackable
        missing = expected - set(df["case"])
        if table == "angular_velocity":
            wrong = sorted(set(df.loc[df["status"] != "unpackable", "case"]) & unpackable)
            if wrong:
                problems.append(f"tables/{table}.csv does not say unpackable for {wrong}")
        if missing:
            problems.append(f"tables/{table}.csv lacks {sorted(missing)}")
if need(root / "claims.csv"):
    claims = pd.read_csv(root / "claims.csv")
    if sorted(claims["claim"]) != list(range(1, 15)):
        problems.append("claims.csv does not hold claims 1-14")
for ext in ("md", "html"):
    need(Path("paper") / f"reproduction_{fidelity}.{ext}")
need(root / "study" / "recommendation.json")
need(root / "tables" / "cost_model.json")
need(root / "tables" / "cost_validation.csv")
if problems:
    sys.exit(f"fidelity {fidelity}: " + "; ".join(problems))
print(f"all outputs of fidelity {fidelity} present for {len(cases)} cases, {len(FIGURES)} figures, {len(TABLES)} tables")
