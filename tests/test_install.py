"""The two installs. The lock files are in step with pyproject.toml (what .ci/lock writes from it):
requirements.lock pins every runtime dependency and nothing top-level that pyproject no longer asks
for, and requirements-test.lock pins the same versions plus the `test` extra; a dependency added to
(or removed from) pyproject.toml without running .ci/lock fails here. And the main job runs in the
main lock's environment: lbmpipe, its command line and the workflow's scripts import none of the
test tools or vtk, which only the extras install."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]
MAIN_LOCK = ROOT / "requirements.lock"
TEST_LOCK = ROOT / "requirements-test.lock"
#: pip-compile's note under a pin that pyproject.toml itself asks for
FROM_PYPROJECT = "lbmpipe (pyproject.toml)"


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def parse_lock(text: str) -> tuple[dict[str, str], set[str]]:
    """``({name: pinned version}, {names pyproject asks for directly})`` of a pip-compile lock
    (names canonical; the top-level ones are those whose ``# via`` notes name pyproject)."""
    pins, top, current = {}, set(), None
    for line in text.splitlines():
        m = re.match(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)", line)
        if m:
            current = canonicalize_name(m.group(1))
            pins[current] = m.group(2)
        elif line.startswith(" ") and FROM_PYPROJECT in line and current:
            top.add(current)
        elif line.strip() and not line.startswith(" ") and not line.startswith("#"):
            raise AssertionError(f"lock line not a name==version pin: {line!r} (regenerate with .ci/lock)")
    return pins, top


def lock_problems(requirements: list[str], text: str, lock_name: str) -> list[str]:
    """What is out of step between ``requirements`` (PEP 508 strings) and a lock's ``text``."""
    pins, top = parse_lock(text)
    wanted = {canonicalize_name(Requirement(r).name): Requirement(r) for r in requirements}
    problems = []
    for name, req in wanted.items():
        if name not in pins:
            problems.append(f"{req} is in pyproject.toml but not pinned in {lock_name}")
        elif not req.specifier.contains(pins[name], prereleases=True):
            problems.append(f"{lock_name} pins {name}=={pins[name]}, outside pyproject's {req}")
    for name in sorted(top - set(wanted)):
        problems.append(f"{lock_name} pins {name} for pyproject.toml, which no longer asks for it")
    return [p + " (run .ci/lock)" for p in problems]


def test_main_lock_pins_exactly_the_runtime_dependencies_within_their_specifiers():
    problems = lock_problems(pyproject()["dependencies"], MAIN_LOCK.read_text(), MAIN_LOCK.name)
    assert not problems, "\n".join(problems)


def test_test_lock_pins_the_runtime_dependencies_and_the_test_extra():
    project = pyproject()
    wanted = project["dependencies"] + project["optional-dependencies"]["test"]
    problems = lock_problems(wanted, TEST_LOCK.read_text(), TEST_LOCK.name)
    assert not problems, "\n".join(problems)


def test_test_lock_runs_the_main_jobs_exact_versions():
    main, _ = parse_lock(MAIN_LOCK.read_text())
    test, _ = parse_lock(TEST_LOCK.read_text())
    assert {n: (v, test.get(n)) for n, v in main.items() if test.get(n) != v} == {}


def test_main_lock_leaves_out_the_test_tools_and_the_field_readers():
    """The point of the split: pytest, selenium and vtk (0.5 GB) are not in the main job's lock."""
    main, _ = parse_lock(MAIN_LOCK.read_text())
    assert not {"pytest", "selenium", "vtk"} & set(main)


def test_test_extra_holds_the_field_readers():
    """The tests read field files back: everything of the `fields` extra is in `test` too."""
    extras = pyproject()["optional-dependencies"]
    names = {canonicalize_name(Requirement(r).name) for r in extras["test"]}
    assert {canonicalize_name(Requirement(r).name) for r in extras["fields"]} <= names


def test_a_dependency_added_or_removed_without_regenerating_is_caught():
    """The check itself: a new pyproject dependency, a stale top-level pin and a pin outside its
    specifier are each reported."""
    text = MAIN_LOCK.read_text()
    deps = pyproject()["dependencies"]
    assert any("not pinned" in p for p in lock_problems(deps + ["somenewpackage>=1"], text, "lock"))
    dropped = next(d for d in deps if canonicalize_name(Requirement(d).name) == "pyevtk")
    assert any("no longer asks" in p for p in lock_problems([d for d in deps if d != dropped], text, "lock"))
    numpy_too_new = [("numpy>=99" if canonicalize_name(Requirement(d).name) == "numpy" else d) for d in deps]
    assert any("outside" in p for p in lock_problems(numpy_too_new, text, "lock"))


#: what only the extras install (`test`, `fields`): the main job must not import them
EXTRAS_ONLY = ("pytest", "_pytest", "selenium", "vtk", "vtkmodules")

#: a child interpreter in which the extras-only packages cannot be imported (as in the main
#: environment): it imports every module of lbmpipe and runs `lbmpipe --help`
WITHOUT_EXTRAS = f"""
import importlib, pkgutil, sys
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in {EXTRAS_ONLY!r}:
            raise ImportError(name + " is not in the main environment")
sys.meta_path.insert(0, Absent())
import lbmpipe
for m in pkgutil.walk_packages(lbmpipe.__path__, "lbmpipe."):
    importlib.import_module(m.name)
from lbmpipe.cli import main
try:
    main(["--help"])
except SystemExit as e:
    sys.exit(e.code)
"""


def test_every_lbmpipe_module_and_the_cli_work_without_the_test_tools_and_vtk():
    res = subprocess.run([sys.executable, "-c", WITHOUT_EXTRAS], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "usage" in res.stdout.lower()


def module_level_imports(source: str) -> set[str]:
    """Top-level package names a module imports when it is loaded (not inside a function)."""
    names = set()

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(child, ast.Import):
                names.update(a.name.partition(".")[0] for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                names.add(child.module.partition(".")[0])
            visit(child)

    visit(ast.parse(source))
    return names


def test_module_level_import_finder_skips_imports_inside_functions():
    source = "import os.path\nfrom vtk import x\nif 1:\n    import yaml\ndef f():\n    import pytest\n"
    assert module_level_imports(source) == {"os", "vtk", "yaml"}


def test_workflow_scripts_and_rules_import_no_test_tool_or_vtk_when_loaded():
    """The scripts Snakemake runs (workflow/scripts) and the Snakefile and its rules load in the
    main environment."""
    problems = []
    for path in sorted((ROOT / "workflow" / "scripts").glob("*.py")):
        bad = module_level_imports(path.read_text()) & set(EXTRAS_ONLY)
        problems += [f"{path.relative_to(ROOT)} imports {name}" for name in sorted(bad)]
    for path in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        for line in path.read_text().splitlines():
            m = re.match(r"^(?:import|from)\s+([\w]+)", line)
            if m and m.group(1) in EXTRAS_ONLY:
                problems.append(f"{path.relative_to(ROOT)}: {line.strip()}")
    assert not problems, "\n".join(problems)
