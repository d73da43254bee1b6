"""Cases the config declares unpackable: a target concentration the packer cannot reach.

A case's ``unpackable`` entry in ``config.yaml`` (``{reason, attempt}``) names why, and the
committed record of the measured packing attempt (``attempt``: ``results/packings/<id>.json``,
status ``unpackable``, with the highest concentration reached). Such a case is planned at no
level: :func:`lbmpipe.reproduction.cases.level_runs` leaves it out, so no packing, scene, run or
statistics job exists for it, whatever ``new_runs`` says. Every reader of a case's
``summary.json`` takes :func:`read_summary`, which gives a declared case without one the record
:func:`record` builds from the declaration (what ``cases.write_unpackable`` writes for a packing
that fails in a run): its tables, figures, claims and the document say ``unpackable`` with the
concentration the attempt reached, never ``not run``.
"""

from __future__ import annotations

import json
from pathlib import Path


def declared(case: dict | None) -> dict | None:
    """The case's ``unpackable`` declaration (``{reason, attempt}``) or None."""
    return (case or {}).get("unpackable") or None


def read_json(path: Path) -> dict | None:
    """A JSON record (a run's summary or statistics), or None where it is absent or unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def record(name: str, case: dict, root: Path | str = ".") -> dict:
    """The ``summary.json`` of a case declared unpackable: status ``unpackable``, the reason, and
    the packing attempt's target, highest concentration reached and message (``attempt`` read
    relative to ``root``, the repository; absent: named in the message, concentrations None)."""
    dec = declared(case) or {}
    attempt = read_json(Path(root) / str(dec.get("attempt", ""))) if dec.get("attempt") else None
    att = attempt or {}
    target = att.get("concentration_target", ((case or {}).get("particles") or {}).get("concentration"))
    reached = att.get("concentration_reached")
    where = (f"packing attempt {dec.get('attempt')}: {att.get('message', '')}" if attempt is not None
             else f"packing attempt {dec.get('attempt')} not found")
    return {"status": "unpackable", "case": name, "declared": True,
            "message": f"unpackable (config.yaml): {dec.get('reason', '')} ({where})",
            "steps": 0, "simulated_seconds": 0.0, "wall_seconds": 0.0, "spinup_s": 0.0,
            "packing": {"packing": att.get("packing"), "concentration_target": target,
                        "concentration_reached": reached, "count": att.get("count"), "seed": att.get("seed"),
                        "message": att.get("message")},
            "particles": {"count": 0, "concentration_target": target, "concentration_achieved": reached}}


def read_summary(case_dir: Path | str, case: dict | None = None, root: Path | str = ".") -> dict | None:
    """``summary.json`` of a case or run directory; for a case declared unpackable (``case``, its
    config entry) that has none, :func:`record`; else None."""
    case_dir = Path(case_dir)
    s = read_json(case_dir / "summary.json")
    if s is not None or not declared(case):
        return s
    name = case_dir.parent.name if case_dir.name.startswith("seed") else case_dir.name
    return record(name, case, root)


def problems(config: dict, root: Path | str = ".") -> list[str]:
    """Config errors of the declarations (one line per problem, ``config error in ...``): a
    particle-free case declared unpackable, or an attempt whose record (read relative to ``root``,
    the repository) says the target packed. An absent record is no error: a working directory
    of its own has no committed packings, and the record then says so."""
    out = []
    for name, case in (config.get("cases") or {}).items():
        dec = declared(case)
        if dec is None:
            continue
        where = f"config error in cases.{name}.unpackable"
        if not (case or {}).get("particles"):
            out.append(f"{where}: a particle-free case cannot be unpackable. Fix: remove the entry")
            continue
        att = read_json(Path(root) / str(dec.get("attempt", "")))
        if att is not None and att.get("status") != "unpackable":
            out.append(f"{where}.attempt: {dec.get('attempt')} says status {att.get('status')!r}, not "
                       "'unpackable'. Fix: remove the declaration: the case packs")
    return out
