"""Numba's on-disk cache follows lbmpipe's sources (``lbmpipe/__init__.py``): numba alone would
keep a cached function that inlines code from an edited module."""

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import lbmpipe

PACKAGE = Path(lbmpipe.__file__).resolve().parent

_PROBE = ("import numba, lbmpipe, os; from numba.core import config; "
          "print(os.environ['NUMBA_CACHE_DIR']); print(config.CACHE_DIR)")


def _cache_folder(root: Path, cache_home: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(XDG_CACHE_HOME=str(cache_home), PYTHONPATH=str(root))
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, cwd=root, check=True, capture_output=True,
                         text=True).stdout.split()
    # numba imported before lbmpipe still uses the folder
    assert out[0] == out[1], out
    return out[0]


def test_an_edit_of_any_module_gives_numba_a_fresh_cache_folder(tmp_path):
    copy = tmp_path / "src"
    shutil.copytree(PACKAGE, copy / "lbmpipe", ignore=shutil.ignore_patterns("__pycache__"))
    home = tmp_path / "cache"
    first = _cache_folder(copy, home)
    assert Path(first).parent == home / "lbmpipe" / "numba" and Path(first).is_dir()
    assert _cache_folder(copy, home) == first  # same sources, same folder: the cache is reused
    top = copy / "lbmpipe" / "solver.py"
    top.write_text(top.read_text() + "\n# edited\n")
    second = _cache_folder(copy, home)
    assert second != first


def test_an_edit_of_a_module_in_a_subpackage_gives_numba_a_fresh_cache_folder(tmp_path):
    # particles/collisions/ compiles the contact package's GJK into its own functions: they live in
    # lbmpipe/particles/collisions/ and lbmpipe/particles/contact/, two folders deep
    copy = tmp_path / "src"
    shutil.copytree(PACKAGE, copy / "lbmpipe", ignore=shutil.ignore_patterns("__pycache__"))
    home = tmp_path / "cache"
    first = _cache_folder(copy, home)
    contact = copy / "lbmpipe" / "particles" / "contact" / "gjk.py"
    contact.write_text(contact.read_text() + "\n# edited\n")
    assert _cache_folder(copy, home) != first


def test_an_explicit_numba_cache_dir_is_left_alone(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, check=True, capture_output=True,
                         text=True).stdout.split()
    assert out == [str(tmp_path / "mine")] * 2


def test_cache_folders_of_other_source_versions_unused_for_two_weeks_are_removed(tmp_path):
    home = tmp_path / "cache"
    numba_dir = home / "lbmpipe" / "numba"
    old, recent = numba_dir / "0000000000000000", numba_dir / "1111111111111111"
    for folder, age_days in ((old, lbmpipe._CACHE_KEEP_DAYS + 1), (recent, lbmpipe._CACHE_KEEP_DAYS - 1)):
        (folder / "x").mkdir(parents=True)
        t = time.time() - age_days * 86400
        os.utime(folder, (t, t))
    current = Path(_cache_folder(PACKAGE.parent, home))
    assert current.is_dir() and current.stat().st_mtime > time.time() - 3600  # marked as used
    assert not old.exists() and recent.is_dir()
