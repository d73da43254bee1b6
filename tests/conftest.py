import sys
from pathlib import Path

# Shared analytic-flow helpers (tests/fluid_cases.py) are imported by tests and the study scripts.
sys.path.insert(0, str(Path(__file__).parent))
