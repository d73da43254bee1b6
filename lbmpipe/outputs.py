"""Output files of a run, in physical units (mm, m/s, m^3/s, s), and the run summary.

Every file and column is documented in docs/outputs.md. Lattice values are converted here
through :class:`lbmpipe.units.Units`, nowhere else.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd

from . import __version__

SUMMARY = "summary.json"


def _sim_time(step: int, dt_s: float) -> str:
    return f"t={step * dt_s:.3f} s"


def progress_text(step: int, dt_s: float, n_fluid: int, elapsed: float) -> str:
    mlups = n_fluid * step / elapsed / 1e6 if elapsed > 0 else 0.0
    return f"{_sim_time(step, dt_s)}, {mlups:.1f} MLUPS"


_SIM_TIME = re.compile(r"^t=\S+ s(, )?")


def progress_bar(total: int, dt_s: float, n_fluid: int, enabled: bool = True, **tqdm_options):
    """tqdm bar over steps (tqdm supplies the ETA); the postfix shows simulated time and MLUPS.

    The run loop sets the postfix (``progress_text``) at the samples only, while tqdm redraws the
    step count at every ``update``; so the bar writes the simulated time of the count it shows at
    every draw, and keeps the MLUPS of the last sample. ``tqdm_options`` override tqdm's (``file``,
    ``mininterval``, ...)."""
    from tqdm import tqdm

    class StepBar(tqdm):
        @property
        def format_dict(self):
            d = super().format_dict
            rest = _SIM_TIME.sub("", d.get("postfix") or "")
            d["postfix"] = _sim_time(self.n, dt_s) + (f", {rest}" if rest else "")
            return d

    options = dict(unit="step", dynamic_ncols=True, mininterval=0.5, desc="lbmpipe") | tqdm_options
    return StepBar(total=total, disable=not enabled, **options)


def replace_atomically(path: Path, write) -> None:
    """``write(tmp)`` to a temporary name beside ``path``, then rename it over ``path``: a reader,
    or a run killed mid-write, never sees a half-written file, and an older complete file stays
    until the new one is."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_flow_rate(out_dir: Path, series, units, scene) -> str:
    """``flow_rate.csv``: sampled flow rate, driving force density, density deviation and the
    profile's core velocity ratio."""
    arr = np.array(series, dtype=np.float64).reshape(-1, 5)
    df = pd.DataFrame({
        "t_s": arr[:, 0] * units.dt_s,
        "q_m3_s": [units.flow_rate_phys(v) for v in arr[:, 1]],
        # force per unit volume (N/m^3), i.e. the driving pressure gradient -dp/dz
        "force_density_N_m3": [units.force_phys(v) / units.dx_m**3 for v in arr[:, 2]],
        "max_density_deviation": arr[:, 3],
        "core_velocity_ratio": arr[:, 4],
    })
    replace_atomically(Path(out_dir) / "flow_rate.csv", lambda tmp: df.to_csv(tmp, index=False))
    return "flow_rate.csv"


def write_profile(out_dir: Path, r, u, u_ref, count, units) -> str:
    """``profile.csv``: time-averaged axial velocity against radius, with the Poiseuille reference."""
    df = pd.DataFrame({
        "r_mm": [units.length_phys(v) * 1e3 for v in r],
        "uz_m_s": [units.velocity_phys(v) for v in u],
        "uz_poiseuille_m_s": [units.velocity_phys(v) for v in u_ref],
        "nodes": count,
    })
    replace_atomically(Path(out_dir) / "profile.csv", lambda tmp: df.to_csv(tmp, index=False))
    return "profile.csv"


def versions() -> dict:
    import numba
    import scipy

    return {"lbmpipe": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "scipy": scipy.__version__, "pandas": pd.__version__}


def host() -> dict:
    """The processor the kernels are compiled for, by LLVM's name (``znver4``, ``skylake-avx512``:
    it sets their vector width, and with it the fluid step's cost per node), and the cores the
    machine offers. The run-cost model keeps the runs of each processor apart
    (``lbmpipe.reproduction.runcost``). ``openblas_coretype``: OpenBLAS's kernel as the environment
    forces it (``auto``: detected), since it sets the rounding of the step's BLAS calls (the flux
    correction's dot product among them) and so a run's bits. No host name."""
    import llvmlite.binding as ll
    import numba

    return {"cpu": str(numba.config.CPU_NAME or ll.get_host_cpu_name()), "cores": os.cpu_count(),
            "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE") or "auto"}


def git_commit() -> str | None:
    """Commit of the source tree the package runs from, with ``-dirty`` if it has changes. The
    generated ``results/`` and ``paper/`` do not count: a pipeline that rewrites the committed
    results is still running the committed code."""
    here = Path(__file__).resolve().parent
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if sha.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ":(top)",
                                ":(top,exclude)results", ":(top,exclude)paper"], cwd=here,
                               capture_output=True, text=True, timeout=5)
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def jsonable(obj, non_finite: list[str] | None = None, where: str = ""):
    """``obj`` as plain JSON values: dataclasses and dicts as objects, tuples and arrays as lists,
    NumPy scalars as Python numbers, and NaN and +-Infinity as ``None`` (strict JSON has no such
    numbers; readers map ``null`` back to NaN). The dotted path of each non-finite value is
    appended to ``non_finite`` if given."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    if isinstance(obj, dict):
        return {str(k): jsonable(v, non_finite, f"{where}.{k}" if where else str(k)) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, non_finite, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        if math.isfinite(v):
            return v
        if non_finite is not None:
            non_finite.append(where or "the value")
        return None
    return obj


def strict_json(obj, **dumps_options) -> str:
    """``obj`` as strict JSON text (RFC 8259, what jq and browsers read): non-finite numbers as
    ``null`` (``jsonable``), then ``json.dumps`` with ``allow_nan=False`` so that nothing else
    can slip a ``NaN`` token through. ``dumps_options`` go to ``json.dumps`` (``indent``, ...)."""
    return json.dumps(jsonable(obj), allow_nan=False, **dumps_options)


def write_json(path: Path, obj, indent: int = 2) -> Path:
    """``path`` holding ``obj`` as strict JSON (``strict_json``) and a final newline."""
    path = Path(path)
    path.write_text(strict_json(obj, indent=indent) + "\n")
    return path


def portable_path(path) -> str:
    """``path`` relative to the working directory if it lies below it, else as given."""
    try:
        return str(Path(path).resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def lattice_record(params) -> dict:
    """The derived lattice parameters as the summary's ``lattice`` block: the collision operator's
    rates as ``omega`` and ``omega_minus`` where ``relaxation`` stands (the operator itself is the
    scene's ``numerics.collision``), so that summaries keep one shape across versions."""
    out = {}
    for f in dataclasses.fields(params):
        if f.name == "relaxation":
            out["omega"], out["omega_minus"] = float(params.omega), float(params.omega_minus)
        else:
            out[f.name] = getattr(params, f.name)
    return out


def write_summary(out_dir: Path, summary: dict, scene, params) -> Path:
    """``summary.json``: the resolved scene, the lattice parameters, effects and timings, status.

    Strict JSON: a value that is not finite (NaN, Infinity: a run that ended unstable) is written
    as ``null``, and ``summary["message"]`` (in the file and in the caller's dict, which
    ``lbmpipe run`` prints) names the values that were not finite. Written to a temporary name and
    renamed, so a reader never sees a half-written summary.
    """
    doc = dict(summary)
    doc["scene"] = scene.model_dump(mode="json")
    # packing files are read at absolute paths; the summary names them from the working directory
    # (the repository, for the pipeline), so summaries made in another clone read the same
    for g in (doc["scene"].get("particles") or {}).get("packed") or []:
        if g.get("file"):
            g["file"] = portable_path(g["file"])
    part = doc.get("particles")
    if isinstance(part, dict) and isinstance(part.get("source"), str) and Path(part["source"]).is_absolute():
        doc["particles"] = dict(part, source=portable_path(part["source"]))
    doc["lattice"] = lattice_record(params)
    doc["versions"] = versions()
    doc["git_commit"] = git_commit()
    doc["host"] = host()
    non_finite: list[str] = []
    doc = jsonable(doc, non_finite)
    if non_finite:
        shown = ", ".join(non_finite[:8]) + (f" and {len(non_finite) - 8} more" if len(non_finite) > 8 else "")
        note = f"Not finite, written as null in {SUMMARY}: {shown}."
        summary["message"] = doc["message"] = " ".join(filter(None, [summary.get("message") or "", note]))
    path = Path(out_dir) / SUMMARY
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=2, sort_keys=False, allow_nan=False) + "\n")
    tmp.replace(path)
    return path
