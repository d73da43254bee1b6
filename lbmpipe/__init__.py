"""lbmpipe: lattice Boltzmann reproduction of Ku & Lin (cylinders and cubes in a crowded pipe flow)."""

import hashlib
import os
import sys
from pathlib import Path

__version__ = "0.1.0"


def cache_root() -> Path:
    """``$XDG_CACHE_HOME/lbmpipe`` (default ``~/.cache/lbmpipe``): numba's cache and the generated
    kernels live under it."""
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "lbmpipe"


#: a numba cache folder of another source version unused this long is removed (a checkout of
#: that version run again recompiles once)
_CACHE_KEEP_DAYS = 14


def _prune_stale(current: Path) -> None:
    import shutil
    import time

    limit = time.time() - _CACHE_KEEP_DAYS * 86400.0
    try:
        for other in current.parent.iterdir():
            if other != current and other.is_dir() and other.stat().st_mtime < limit:
                shutil.rmtree(other, ignore_errors=True)
    except OSError:
        pass  # a cache that cannot be listed is left as it is


def _numba_cache_by_source() -> None:
    """Put numba's on-disk cache in a folder named after a hash of lbmpipe's sources, unless
    ``NUMBA_CACHE_DIR`` is set.

    Why: numba invalidates a cached function when *its own* source file changes, not when a
    function it inlines from another module does. ``particles/collisions/`` compiles the contact
    package's GJK (``particles/contact/``) into its own functions, and the contact modules inline
    each other's helpers, so after an edit of the GJK the cached collision step would keep
    running the old one, silently (it happened while timing a change to the contact code).
    With the folder keyed by every source file, any edit starts a fresh cache. Each import marks
    its folder as used; folders of other source versions unused for ``_CACHE_KEEP_DAYS`` are
    removed (each holds 10-40 MB, and every edit of the package makes one).
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):  # every subpackage too: a kernel inlines code from any of them
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    folder = cache_root() / "numba" / digest.hexdigest()[:16]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)
    except OSError:
        return  # not writable: numba's default (beside the sources) is still correct for a fresh checkout
    _prune_stale(folder)
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba" in sys.modules:  # numba read its settings at import: make it read them again
        from numba.core import config

        config.reload_config()


_numba_cache_by_source()
