"""The pipeline's config file (``config.yaml``) read strictly, as the scenes are: a key given twice,
a list as a key, a file that is not UTF-8 YAML are refused with one line each, before any job.

Snakemake reads ``configfile:`` with its own YAML loader, which keeps the last of two equal keys;
the Snakefile therefore reads its config files again here (``config_file_problems``) and stops on
the first problem, and ``lbmpipe check-config`` reads the file here (``read_config``).
"""

from __future__ import annotations

from pathlib import Path

from lbmpipe.errors import SceneError
from lbmpipe.inputs import InputError
from lbmpipe.scene import parse_strict_yaml

#: a config is a few kilobytes; far larger is not one (and is not read into memory)
MAX_CONFIG_BYTES = 1_000_000


def read_config(path: str | Path) -> dict:
    """The pipeline config at ``path`` as a dict; InputError (kind ``config``, one line naming the
    key or the file) if it cannot be read, is not UTF-8 YAML, gives a key twice or uses a list or
    mapping as a key. Whether it holds a mapping and what the schema says is ``config_problems``'
    business (``lbmpipe.reproduction.cases``)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise InputError(str(path), f"the file has {size:,} bytes; a config is a few kilobytes",
                             "give the pipeline's YAML config, e.g. config.yaml", kind="config")
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(str(path), f"cannot read it ({type(exc).__name__}: {' '.join(str(exc).split())[:200]})",
                         "give a readable UTF-8 YAML file", kind="config") from None
    try:
        return parse_strict_yaml(text, str(path))
    except SceneError as exc:  # the scene loader's one line, as a config error
        where = exc.field if exc.field == str(path) else f"{exc.field} ({path})"  # a key given twice: the key
        raise InputError(where, exc.message, exc.fix, kind="config") from None


def config_file_problems(paths) -> list[str]:
    """One line (``config error in ...``) for the first problem of each config file in ``paths``
    that ``read_config`` refuses; empty if all read. For the Snakefile, which passes
    ``workflow.configfiles`` (``configfile:`` and ``--configfile``)."""
    out = []
    for path in paths:
        try:
            read_config(path)
        except InputError as exc:
            out.append(exc.line())
    return out
