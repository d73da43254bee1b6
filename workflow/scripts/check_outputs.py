"""CI check: every figure and case output of a fidelity level exists and covers every case."""

import json
import sys
from pathlib import Path

import yaml

fidelity = sys.argv[1]
config = yaml.safe_load(Path("config.yaml").read_text())
root = Path("results") / fidelity
missing = []
for case in config["cases"]:
    for name in ("summary.json", "flow_rate.csv", "profile.csv"):
        if not (root / "cases" / case / name).exists():
            missing.append(f"cases/{case}/{name}")
    summary = root / "cases" / case / "summary.json"
    if summary.exists() and json.loads(summary.read_text())["status"] != "completed":
        missing.append(f"cases/{case}: status not completed")
for fig in ("fig10_profiles",):
    for ext in ("pdf", "png"):
        if not (root / "figures" / f"{fig}.{ext}").exists():
            missing.append(f"figures/{fig}.{ext}")
if missing:
    sys.exit(f"missing or failed outputs under {root}: " + ", ".join(missing))
print(f"all outputs of fidelity {fidelity} present for {len(config['cases'])} cases")
