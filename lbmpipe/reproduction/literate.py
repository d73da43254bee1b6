"""The literate reproduction: the paper's equations linked to the code, and the document that puts
the method, the parameters, the figures, the claims and the costs of one fidelity level together.

Equation links. Docstrings cite the paper's equations by number (``Eq. (N)``, ``Eqs. (N)-(M)``,
``Eqs. (N), (M)``, ``Eq. (N, M)``); :func:`equation_index` reads them with :mod:`ast` (module,
class and function docstrings of ``lbmpipe/**/*.py``), so the index is the code's own statement of
where each equation lives and cannot drift from it. Each link in the document carries a title
``"Eq. N: qualname"`` that :func:`check_links` uses to verify that the line still holds that
definition and that its docstring still cites the equation.

Document. :func:`build_document` renders ``paper/reproduction.md.j2`` (Jinja2) from a results
directory ``results/<fid>/``. The template receives data only: every number in the text is read
from the results (or derived from ``config.yaml`` through :func:`lbmpipe.units.derive`); a section
whose input is absent says ``not built at this level: <file> missing``. It is laid out as a paper:
an abstract with the verdict in numbers, the method (the key equations as displayed maths beside a
short excerpt of their code, :data:`KEY_EQUATIONS`; Fig. 3 as one gallery of the snapshots), one
section per figure of the paper (what the paper says, what we see, why: the measured diagnostics of
its cases), the claims in one line each, the limitations and the run health; the long tables
follow as appendices (:func:`main_text` is everything before them). The web page beside it
(``.html``: maths as MathML, contents, anchors per claim and figure) is :mod:`lbmpipe.reproduction.webpage`'s.
"""

from __future__ import annotations

import ast
import json
import math
import os
import re
from pathlib import Path
from typing import NamedTuple

N_EQUATIONS = 21

#: The paper's equations as the project reads them (paper/reading.md, section 1), Markdown with LaTeX maths
#: (``$...$``; the web page renders it as MathML, :mod:`lbmpipe.reproduction.webpage`).
EQUATIONS: dict[int, str] = {
    1: r"$\partial_t f_i + \mathbf{e}_i \cdot \nabla f_i = \Omega_i$ (lattice Boltzmann equation)",
    2: r"$\Omega_i = -\left(f_i - f_i^{eq}\right) / \tau$ (BGK collision)",
    3: r"$f_i^{eq} = \rho w_i \left[1 + \frac{3\,\mathbf{e}_i \cdot \mathbf{u}}{c^2} + \frac{9\,(\mathbf{e}_i \cdot "
       r"\mathbf{u})^2}{2c^4} - \frac{3\,u^2}{2c^2}\right]$, $c = \Delta x / \Delta t$",
    4: r"$\rho = \sum_i f_i$, $\rho\,\mathbf{u} = \sum_i f_i\,\mathbf{e}_i$",
    5: r"weakly compressible Navier-Stokes: $\partial_t \rho + \nabla \cdot (\rho\,\mathbf{u}) = 0$, with "
       r"$P = \rho\,c_s^2$, $c_s^2 = c^2/3$",
    6: r"$\partial_t(\rho\,\mathbf{u}) + \nabla \cdot (\rho\,\mathbf{u}\mathbf{u}) = -\nabla P + \nabla \cdot "
       r"\left[\rho\nu\left(\nabla\mathbf{u} + (\nabla\mathbf{u})^T\right)\right]$, "
       r"$\nu = c^2\,\Delta t\,(\tau - \tfrac{1}{2})/3$",
    7: r"$w_0 = 2/9$, $w_{1..6} = 1/9$, $w_{7..14} = 1/72$ (D3Q15, velocities of Table 1)",
    8: r"$f_{i'}(\mathbf{x}, t+1) = f_i(\mathbf{x}, t_+) - 2 B_i\,(\mathbf{e}_i \cdot \mathbf{u}_b)$, "
       r"$B_i = 3\rho w_i / c^2$, $\mathbf{u}_b = \mathbf{U} + \boldsymbol{\Omega} \times "
       r"(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i - \mathbf{X})$ (Ladd's moving bounce-back)",
    9: r"$\mathbf{F}(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i, t + \tfrac{1}{2}) = 2\,\mathbf{e}_i\left[f_i(\mathbf{x}, "
       r"t_+) - B_i\,(\mathbf{e}_i \cdot \mathbf{u}_b)\right]$ (force on a boundary link)",
    10: r"$\mathbf{T}(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i, t + \tfrac{1}{2}) = "
        r"(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i - \mathbf{X}) \times "
        r"\mathbf{F}(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i, t + \tfrac{1}{2})$ (torque of a link)",
    11: r"$\mathbf{F}_p = \sum_{\mathrm{links}} \mathbf{F}(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i, t + \tfrac{1}{2})$ "
        r"(total force on a particle)",
    12: r"$\mathbf{T}_p = \sum_{\mathrm{links}} \mathbf{T}(\mathbf{x} + \tfrac{1}{2}\mathbf{e}_i, t + \tfrac{1}{2})$ "
        r"(total torque on a particle)",
    13: r"$\frac{d\Omega_x}{dt} = \frac{T_x}{I_{xx}} + \frac{(I_{yy} - I_{zz})\,\Omega_y \Omega_z}{I_{xx}}$, and "
        r"cyclic (Euler's equations, body frame)",
    14: r"orientation as a unit quaternion $q = (q_0, q_1, q_2, q_3)$ (Evans 1977), no Euler-angle singularity",
    15: r"quaternion kinematics $\frac{dq}{dt} = \frac{1}{2}\, q \otimes (0, \boldsymbol{\Omega}_{\mathrm{body}})$",
    16: r"$m_1 \mathbf{v}_1' = m_1 \mathbf{v}_1 - I\,\mathbf{p}$, "
        r"$m_2 \mathbf{v}_2' = m_2 \mathbf{v}_2 + I\,\mathbf{p}$ "
        r"(collision impulse $I$, normal $\mathbf{p}$ from 1 to 2)",
    17: r"$k = -\frac{v_{1p}' - v_{2p}'}{v_{1p} - v_{2p}}$ (restitution; normal contact-point velocities)",
    18: r"$J_1 \boldsymbol{\omega}_{1s}' = J_1 \boldsymbol{\omega}_{1s} - \mathbf{l}_{1s} \times (I\,\mathbf{p}_s)$, "
        r"$J_2 \boldsymbol{\omega}_{2s}' = J_2 \boldsymbol{\omega}_{2s} + \mathbf{l}_{2s} \times (I\,\mathbf{p}_s)$",
    19: r"$I = \frac{m_1 (1+k)(v_{1p} - v_{2p})}{1 + \frac{m_1}{m_2} + m_1 \left([A_1 J_1^{-1} (\mathbf{l}_{1s} "
        r"\times \mathbf{p}_{1s})] \times \mathbf{l}_1\right) \cdot \mathbf{p} + m_1 \left([A_2 J_2^{-1} "
        r"(\mathbf{l}_{2s} \times \mathbf{p}_{2s})] \times \mathbf{l}_2\right) \cdot \mathbf{p}}$",
    20: r"$A$ = rotation matrix (body → lab) of the particle's quaternion",
    21: r"$I = \frac{m_1 (1+k)(-v_{1p})}{1 + m_1 \left([A_1 J_1^{-1} (\mathbf{l}_{1s} \times \mathbf{p}_{1s})] "
        r"\times \mathbf{l}_1\right) \cdot \mathbf{p}}$ (wall: $m_2 \to \infty$, $v_{2p} = 0$)",
}

#: Section of the paper each equation belongs to (for grouping in the document).
EQUATION_GROUPS: list[tuple[str, list[int]]] = [
    ("Fluid: lattice BGK on D3Q15", [1, 2, 3, 4, 5, 6, 7]),
    ("Moving solid boundaries: Ladd's link bounce-back", [8, 9, 10, 11, 12]),
    ("Rigid-body rotation", [13, 14, 15]),
    ("Collisions: instantaneous impulse", [16, 17, 18, 19, 20, 21]),
]

#: The paper's figure captions, from its text (the OCR of the paper; Fig. 7 has no caption there).
PAPER_CAPTIONS: dict[str, str] = {
    "3": "Fig. 3 Pipe flow and coordinate system",
    "4": "Fig. 4 Effect of cylindrical particle aspect ratio on angular velocity about various axes "
         "(30% in particle concentration, 26 in Reynolds number)",
    "5": "Fig. 5 Effect of cubic particle concentration on angular velocity about various axes (9.4 in "
         "Reynolds number, 8 mm×8 mm in size, LC: 30% particle concentration; HC: 50% particle concentration)",
    "6": "Fig. 6 Effect of Reynolds number on angular velocity about various axes (30% in particle "
         "concentration, 24 mm×24 mm in size of cubic particles, LF: Re=9.4; HF: Re=26)",
    "7a": "Fig. 7a (no caption in the paper's text; the text: \"The effects of particles shape and size on "
          "angular velocity about various axes are plotted in Figs. 7a and 7b\")",
    "7b": "Fig. 7b (no caption in the paper's text; see Fig. 7a)",
    "8": "Fig. 8 Numerical results (a) and experimental results (b) of orientation distribution for "
         "cylindrical particles (30% in concentration, LF: Re=9.4; HF: Re=26)",
    "9": "Fig. 9 Numerical results (a) and experimental results (b) of orientation distribution for cubic "
         "particles (30% in particle concentration, LF: Re=9.4; HF: Re=26)",
    "10": "Fig. 10 Velocity profiles with and without cylindrical particles at the outlet of pipe (30% in "
          "concentration, 26 in Reynolds number, 16 mm×16 mm in size)",
}

#: Our caption when ``lbmpipe.reproduction.figures.FIGURE_CAPTIONS`` has none (paper/reading.md, section 3).
FALLBACK_CAPTIONS: dict[str, str] = {
    "3": "Snapshot of the particles in the pipe (case in the file name).",
    "4": "Mean |angular velocity| (rad/s) about x, y, z: cylinders 16x16 and 16x24 mm, 30 %, Re 26.",
    "5": "Mean |angular velocity| (rad/s) about x, y, z: 8 mm cubes, Re 9.4, 30 % (LC) and 50 % (HC).",
    "6": "Mean |angular velocity| (rad/s) about x, y, z: 24 mm cubes, 30 %, Re 9.4 (LF) and Re 26 (HF).",
    "7a": "Shape and size: cubes 8/16/24 mm and cylinders 8x8/16x16 mm, 30 %, Re 9.4 (our choice of cases).",
    "7b": "Shape and size: cubes 8/16/24 mm and cylinders 8x8/16x16 mm, 30 %, Re 26 (our choice of cases).",
    "8": "Distribution of the angle between the cylinder axis and the pipe axis, 30 %, Re 9.4 and Re 26.",
    "9": "Distribution of the cube orientation angle folded into 0-45 degrees, 30 %, Re 9.4 and Re 26.",
    "10": "Time-averaged axial velocity against radius, against the Hagen-Poiseuille parabola (dashed).",
}

#: The paper's statement of its computing cost ("It almost takes 24 h to make the statistical average
#: ... reach a relatively steady state"), per case.
PAPER_HOURS_PER_CASE = 24.0

#: Where the paper is silent or inconsistent and the code decides (paper/reading.md); ``{...}`` fields are
#: filled from the config so that no number is typed here.
DECISIONS: list[tuple[str, str]] = [
    ("Viscosity", "The two flow rates imply different viscosities; ν is taken from the Reynolds number "
                  r"($\mathrm{Re} = U D / \nu$, $U = Q / A$), not from a fluid property (paper/reading.md, D2)."),
    ("Driving", "Periodic inlet and outlet: the flow is driven by a body force (pressure gradient) that a "
                "controller adjusts to hold the mixture flow rate Q (`lbmpipe.effects`)."),
    ("Time step at Re 26", "The paper's dt gives a centre-line Mach number near the limit of the scheme "
                           "at Re 26; every level multiplies dt there by {re26_dt_factors} (config "
                           "`re26_dt_factor`); the parameter table shows the resulting τ and Mach."),
    ("Coarser levels", "Levels coarser than the paper's lattice keep the paper's Mach number (dt ∝ dx, "
                       "acoustic scaling); τ then follows from Re (`lbmpipe.reproduction.cases`)."),
    ("Angular-velocity statistic", "Not defined by the paper: the mean of |Ω_x|, |Ω_y|, |Ω_z| in the lab "
                                   "frame over particles and samples after spin-up, with a 95 % confidence "
                                   "interval from batch means."),
    ("Cube orientation", "The experiment saw 2-D projections: the projected angle folded into 0-45 degrees "
                         "is reported, and also the 3-D angle between the pipe axis and the nearest cube "
                         "axis (0-54.7 degrees)."),
    ("Fig. 7 cases", "The text does not say which cases Figs. 7a/7b show; we take 30 %, (a) Re 9.4, "
                     "(b) Re 26, cubes 8/16/24 mm and cylinders 8x8/16x16 mm."),
    ("Quaternion convention", "Any consistent convention is allowed (Eqs. (14)-(15)); ours is "
                              r"$\frac{dq}{dt} = \frac{1}{2}\, q \otimes (0, \boldsymbol{\Omega}_{\mathrm{body}})$, "
                              "body → lab, pinned by the tests."),
    ("Restitution", "Collisions are \"instantaneous and elastic\": k = 1, kept a parameter (Eq. (17))."),
    ("Unreachable concentrations", "A packing that cannot reach its target is reported as not packable "
                                   "with the concentration it reached; a different concentration is never "
                                   "run silently."),
    ("Films thinner than one spacing", "Where a particle nearly touches the wall or another particle, the "
                                       "fluid between them is a film of single nodes with one or two fluid "
                                       "links; the moving bounce-back (Eq. (8)) behind a receding surface "
                                       "drains it faster than those links refill it, and the densest Re 26 "
                                       "cases diverged. The sweep holds such nodes at the density "
                                       "`numerics.density_floor` (0.5) by adding mass at zero momentum; each "
                                       "summary and the stability table report the mass added "
                                       "(`lbmpipe.effects.StreamCollide`)."),
    ("Experimental data", "The values of Zitoun et al. are not in our text and are never invented; a figure "
                          "shows them only from a data file whose source is stated."),
]


class Ref(NamedTuple):
    """Where an equation is implemented: file relative to the repository, qualified name
    (``<module>`` for a module docstring), line of the ``def``/``class`` (1 for a module)."""

    module: str
    qualname: str
    line: int


_NUM = r"\d+[a-z]?"
_GROUP = rf"\(\s*{_NUM}(?:\s*,\s*{_NUM})*\s*\)"
_CITE = re.compile(rf"\bEqs?\.\s*({_GROUP}(?:\s*(?:-|–|—|,|and|to)\s*{_GROUP})*)")
_PART = re.compile(rf"({_GROUP})|(-|–|—|to)")


def _href(target: Path, out_dir: Path) -> str:
    """``target``'s path relative to ``out_dir`` (the document's folder), with forward slashes."""
    return os.path.relpath(Path(target).resolve(), Path(out_dir).resolve()).replace(os.sep, "/")


def cited_equations(text: str) -> set[int]:
    """Equation numbers a docstring cites: ``Eq. (N)``, ``Eq. (Na)`` (a sub-equation counts as N),
    ``Eqs. (N)-(M)`` (a range), ``Eqs. (N), (M)``, ``Eqs. (N) and (M)``, ``Eq. (N, M)``."""
    out: set[int] = set()
    for m in _CITE.finditer(text or ""):
        prev: int | None = None
        pending_range = False
        for part in _PART.finditer(m.group(1)):
            if part.group(2):
                pending_range = True
                continue
            nums = [int(re.match(r"\d+", s.strip()).group()) for s in part.group(1).strip("() ").split(",")]
            if pending_range and prev is not None:
                out.update(range(min(prev, nums[0]), max(prev, nums[0]) + 1))
            out.update(nums)
            prev = nums[-1]
            pending_range = False
    return out


def _docstring_owners(tree: ast.Module):
    """(qualname, node, docstring) of the module, its classes and functions (nested too)."""
    yield "<module>", tree, ast.get_docstring(tree, clean=False)

    def walk(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                qual = f"{prefix}{child.name}"
                yield qual, child, ast.get_docstring(child, clean=False)
                yield from walk(child, qual + ".")

    yield from walk(tree, "")


def equation_index(package_dir: Path) -> dict[int, list[Ref]]:
    """Equation number -> the places whose docstring cites it, from ``package_dir/**/*.py``.

    Functions and classes come before module docstrings, each group in file and line order; the
    module path is relative to the repository (the parent of ``package_dir``)."""
    package_dir = Path(package_dir).resolve()
    root = package_dir.parent
    index: dict[int, list[Ref]] = {}
    for path in sorted(package_dir.rglob("*.py")):  # the subpackages too
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        rel = path.relative_to(root).as_posix()
        for qual, node, doc in _docstring_owners(tree):
            line = 1 if qual == "<module>" else node.lineno
            for n in cited_equations(doc or ""):
                index.setdefault(n, []).append(Ref(rel, qual, line))
    for refs in index.values():
        refs.sort(key=lambda r: (r.qualname == "<module>", r.module, r.line))
    return dict(sorted(index.items()))


def _link(ref: Ref, eq: int, repo_root: Path, out_dir: Path) -> str:
    target = _href(Path(repo_root).resolve() / ref.module, out_dir)
    return f'[{ref.module}:L{ref.line}]({target}#L{ref.line} "Eq. {eq}: {ref.qualname}")'


_LINK = re.compile(r'\[[^\]]*\]\(([^)\s#]+\.py)#L(\d+)(?:\s+"Eq\. (\d+): ([^"]+)")?\)')


def _owner_at(tree: ast.Module, line: int, qualname: str):
    for qual, node, doc in _docstring_owners(tree):
        if qual == qualname and (1 if qual == "<module>" else node.lineno) == line:
            return node, doc
    return None, None


def check_links(md_path: Path, repo_root: Path) -> list[str]:
    """Stale source links of a rendered document: the file is gone, the line is past its end, the
    line no longer holds the cited ``def``/``class`` (or the module docstring), or that docstring
    no longer cites the equation. One message per stale link; an empty list means all are fresh."""
    md_path = Path(md_path)
    repo_root = Path(repo_root).resolve()
    problems: list[str] = []
    trees: dict[Path, ast.Module | None] = {}
    for m in _LINK.finditer(md_path.read_text(encoding="utf-8")):
        rel, line = m.group(1), int(m.group(2))
        target = (md_path.parent / rel).resolve()
        shown = target.relative_to(repo_root).as_posix() if target.is_relative_to(repo_root) else str(target)
        if not target.is_file():
            problems.append(f"{shown}#L{line}: file missing")
            continue
        if target not in trees:
            try:
                trees[target] = ast.parse(target.read_text(encoding="utf-8"))
            except SyntaxError:
                trees[target] = None
        tree = trees[target]
        n_lines = len(target.read_text(encoding="utf-8").splitlines())
        if line > n_lines:
            problems.append(f"{shown}#L{line}: past the end of the file ({n_lines} lines)")
            continue
        if m.group(3) is None:
            continue  # a plain source link: existence and range are all it claims
        eq, qual = int(m.group(3)), m.group(4)
        if tree is None:
            problems.append(f"{shown}#L{line}: file does not parse")
            continue
        node, doc = _owner_at(tree, line, qual)
        if node is None:
            problems.append(f"{shown}#L{line}: line no longer holds {qual} (Eq. ({eq}))")
        elif eq not in cited_equations(doc or ""):
            problems.append(f"{shown}#L{line}: docstring of {qual} no longer cites Eq. ({eq})")
    return problems


# --------------------------------------------------------------------------------------------------
# document data


def _read_csv(path: Path):
    import pandas as pd

    try:
        return pd.read_csv(path)
    except (FileNotFoundError, pd.errors.EmptyDataError):
        return None


def fmt(x, digits: int = 3) -> str:
    """A number for the text: ``digits`` significant digits, integers as integers, NaN as an en dash."""
    if x is None:
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(v):
        return "–"
    if math.isinf(v):
        return "∞" if v > 0 else "-∞"
    if v == int(v) and abs(v) < 1e6:
        return str(int(v))
    if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e6):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}" if abs(v) >= 10 ** (digits - 1) else f"{float(f'{v:.{digits}g}'):g}"


def _cell(v) -> str:
    return fmt(v).replace("|", "\\|").replace("\n", " ")


def table_of(df, columns: list[str] | None = None) -> dict:
    """A DataFrame as ``{"columns": [...], "rows": [[str, ...], ...]}`` for the template."""
    cols = [c for c in (columns or list(df.columns)) if c in df.columns]
    return {"columns": cols, "rows": [[_cell(v) for v in row] for row in df[cols].itertuples(index=False)]}


def method_section(repo_root: Path, out_dir: Path) -> tuple[list[dict], list[int]]:
    """Equation groups with each equation's statement and its source links; and the equations that
    no docstring cites (the document states them as missing)."""
    index = equation_index(Path(repo_root) / "lbmpipe")
    groups = []
    for title, numbers in EQUATION_GROUPS:
        eqs = []
        for n in numbers:
            refs = index.get(n, [])
            code = [r for r in refs if r.qualname != "<module>"] or refs
            links = [{"name": r.qualname if r.qualname != "<module>" else f"{r.module} (module)",
                      "link": _link(r, n, repo_root, out_dir)} for r in code]
            eqs.append({"number": n, "text": EQUATIONS[n], "links": links,
                        "refs_md": "; ".join(f"`{lk['name']}` {lk['link']}" for lk in links)})
        groups.append({"title": title, "equations": eqs})
    return groups, [n for n in range(1, N_EQUATIONS + 1) if n not in index]


def parameter_rows(config: dict) -> tuple[list[dict], list[str]]:
    """Derived lattice values of the particle-free pipe at each fidelity level and Reynolds number
    (``lbmpipe.reproduction.cases.case_scene`` -> ``Scene`` -> ``lbmpipe.units.derive``)."""
    from .cases import FLOWS, case_scene
    from ..scene import Scene, SceneError
    from ..units import derive

    rows, errors = [], []
    for fid_name, fid in (config.get("fidelities") or {}).items():
        for re_ in sorted(FLOWS):
            try:
                data = case_scene(f"flow_re{re_:g}", {"reynolds": re_}, fid_name, fid)
                scene = Scene.model_validate(data)
                p = derive(scene)
            except (SceneError, ValueError) as exc:
                errors.append(f"{fid_name}, Re {fmt(re_)}: {exc}")
                continue
            rows.append({
                "fidelity": fid_name, "reynolds": fmt(re_), "flow_rate": fmt(FLOWS[re_], 4),
                "dx_mm": fmt(scene.numerics.dx_mm), "dt_ms": fmt(scene.numerics.dt_s * 1e3),
                "shape": " × ".join(str(s) for s in p.shape), "nu_m2_s": fmt(p.units.viscosity_phys(p.nu_lu))
                if hasattr(p.units, "viscosity_phys") else fmt(p.nu_lu * p.units.dx_m**2 / p.units.dt_s),
                "nu_lu": fmt(p.nu_lu), "tau": fmt(p.tau), "u_max_lu": fmt(p.u_max_lu), "mach": fmt(p.mach_max),
                "steps": fmt(p.n_steps), "spinup_steps": fmt(p.spinup_steps),
                "duration_s": fmt(scene.run.duration_s),
            })
    return rows, errors


def case_rows(config: dict, fid_dir: Path) -> list[dict]:
    """The config's case matrix with, where the results have them, the achieved concentration and
    the status (``tables/packing.csv``, ``cases/<case>/summary.json``)."""
    packing = _read_csv(Path(fid_dir) / "tables" / "packing.csv")
    pk = {} if packing is None else {r["case"]: r for r in packing.to_dict("records")}
    rows = []
    for name, case in (config.get("cases") or {}).items():
        p = case.get("particles") or {}
        size = (f"{fmt(p['diameter_mm'])} × {fmt(p['length_mm'])}" if p.get("shape") == "cylinder"
                else fmt(p["edge_mm"]) if p.get("shape") == "cube" else "–")
        summary_path = Path(fid_dir) / "cases" / name / "summary.json"
        status = "not run"
        achieved = pk.get(name, {}).get("concentration_achieved")
        if summary_path.is_file():
            s = json.loads(summary_path.read_text())
            status = s.get("status", "?")
            if achieved is None:
                achieved = (s.get("particles") or {}).get("concentration_achieved")
        rows.append({"case": name, "reynolds": fmt(case["reynolds"]), "shape": p.get("shape", "none"),
                     "size_mm": size,
                     "target": fmt(100 * p["concentration"]) if "concentration" in p else "–",
                     "achieved": fmt(100 * achieved) if achieved is not None else "–",
                     "collisions": fmt(bool(case.get("collisions", True))) if p else "–",
                     "status": status})
    return rows


def _figure_key(stem: str) -> str:
    m = re.match(r"fig(\d+[ab]?)", stem)
    return m.group(1) if m else stem


def _our_caption(stem: str) -> tuple[str, str]:
    """Our caption for a figure file stem and where it came from."""
    key = _figure_key(stem)
    try:
        from . import figures

        caps = getattr(figures, "FIGURE_CAPTIONS", None)
    except Exception:  # a broken figures module must not stop the document
        caps = None
    if caps:
        for k in (stem, f"fig{key}", key, key.rstrip("ab") if key[:-1].isdigit() else None):
            if k is not None and k in caps:
                return str(caps[k]), "lbmpipe.reproduction.figures.FIGURE_CAPTIONS"
    return FALLBACK_CAPTIONS.get(key, "(no caption)"), "fallback (lbmpipe.reproduction.literate)"


def _fig_sort(stem: str):
    m = re.match(r"fig(\d+)([ab]?)", stem)
    return (int(m.group(1)), m.group(2), stem) if m else (999, "", stem)


def figure_entries(fid_dir: Path, out_dir: Path) -> list[dict]:
    fig_dir = Path(fid_dir) / "figures"
    out = []
    for png in sorted(fig_dir.glob("fig*.png"), key=lambda p: _fig_sort(p.stem)):
        key = _figure_key(png.stem)
        ours, source = _our_caption(png.stem)
        pdf = png.with_suffix(".pdf")
        out.append({"key": key, "stem": png.stem,
                    "image": _href(png, out_dir),
                    "pdf": _href(pdf, out_dir) if pdf.is_file() else None,
                    "ours": ours, "ours_source": source,
                    "paper": PAPER_CAPTIONS.get(key.rstrip("ab") if key not in PAPER_CAPTIONS else key,
                                                "(no such figure in the paper)")})
    return out


def _rel(path: Path, fid_dir: Path) -> str:
    return Path(path).relative_to(Path(fid_dir)).as_posix()


def runtime_section(fid_dir: Path, fidelity: str) -> dict:
    """Run cost per case (this level) and per level (every ``results/<level>/tables/runtime.csv``
    beside this one), beside the paper's hours per case."""
    fid_dir = Path(fid_dir)
    df = _read_csv(fid_dir / "tables" / "runtime.csv")
    sec = {"paper_hours": fmt(PAPER_HOURS_PER_CASE), "cases": None, "levels": [], "model": None}
    from .health import read_json
    from .runcost import UNRECORDED

    model = read_json(fid_dir / "tables" / "cost_model.json")
    val = _read_csv(fid_dir / "tables" / "cost_validation.csv")
    if model is not None and model.get("n_runs"):
        sec["model"] = {"formula": model.get("formula", ""), "n_runs": fmt(model.get("n_runs")),
                        "families": fmt(model.get("families")), "n_validated": fmt(model.get("n_validated")),
                        "median_pct": fmt(100 * float(model.get("median_abs_rel_error", float("nan")))),
                        "max_pct": fmt(100 * float(model.get("max_abs_rel_error", float("nan")))),
                        "median_share_pct": fmt(100 * float(model.get("median_abs_rel_error_median_share", float("nan")))),
                        "max_share_pct": fmt(100 * float(model.get("max_abs_rel_error_median_share", float("nan")))),
                        "share": fmt(model.get("median_cpu_share")),
                        "ns_node": fmt(1e9 * model.get("s_per_node_update", 0.0)),
                        "ns_link": fmt(1e9 * model.get("s_per_link_update", 0.0)),
                        "us_particle": fmt(1e6 * model.get("s_per_particle_step", 0.0)),
                        "ms_step": fmt(1e3 * model.get("s_per_step", 0.0)), "intercept_s": fmt(model.get("intercept_s")),
                        "hosts": [{"cpu": cpu, "n_runs": fmt(h.get("n_runs")), "families": fmt(h.get("families")),
                                   "n_validated": fmt(h.get("n_validated")),
                                   "ns_node": fmt(1e9 * h.get("s_per_node_update", 0.0)),
                                   "median_pct": fmt(100 * float(h.get("median_abs_rel_error", float("nan")))),
                                   "median_share_pct": fmt(100 * float(h.get("median_abs_rel_error_median_share",
                                                                             float("nan"))))}
                                  for cpu, h in sorted((model.get("hosts") or {}).items())],
                        "unrecorded": fmt((model.get("runs_by_host") or {}).get(UNRECORDED, 0)),
                        "table": table_of(val, ["run", "family", "host", "steps", "particles", "links", "wall_s",
                                                "predicted_s", "rel_error", "cpu_share", "rel_error_median_share",
                                                "fitted_host"])
                        if val is not None and len(val) else None}
    if df is not None:
        d = df.copy()
        if "wall_s" in d:
            d["wall_h"] = d["wall_s"] / 3600.0
            d["fraction_of_paper"] = d["wall_h"] / PAPER_HOURS_PER_CASE
        sec["cases"] = table_of(d, ["case", "status", "steps", "simulated_s", "wall_s", "wall_h", "s_per_step",
                                    "mlups", "particles", "max_rss_mb", "fraction_of_paper"])
    for level_dir in sorted(p for p in fid_dir.parent.iterdir() if p.is_dir()) if fid_dir.parent.is_dir() else []:
        lv = _read_csv(level_dir / "tables" / "runtime.csv")
        if lv is None or "wall_s" not in lv or len(lv) == 0:
            continue
        ran = lv[~lv["status"].astype(str).isin(["unpackable", "not run"])] if "status" in lv else lv
        w = ran["wall_s"].astype(float)
        sec["levels"].append({"level": level_dir.name, "cases": fmt(len(ran)),
                              "total_h": fmt(w.sum() / 3600.0), "median_case_h": fmt(w.median() / 3600.0),
                              "max_case_h": fmt(w.max() / 3600.0),
                              "median_vs_paper": fmt(w.median() / 3600.0 / PAPER_HOURS_PER_CASE),
                              "this": level_dir.name == fidelity})
    return sec


def method_comparison_section(fid_dir: Path, fidelity: str, config: dict, out_dir: Path) -> dict | None:
    """What the method changes (``lbmpipe.reproduction.methods``): for a level another one
    compares with, that level, its runs done and planned, and the comparison's summary, claims
    and paired runs (``results/<level>/method/``); for an accurate-method level, the level it is
    compared with; else None."""
    from .health import read_json
    from .methods import comparison_level

    fid = (config.get("fidelities") or {}).get(fidelity) or {}
    if fid.get("compare_with"):
        # the paired runs are shown in the compared level's document
        return {"is_accurate": True, "paper_level": fid["compare_with"], "runs": None}
    other = comparison_level(config, fidelity)
    if other is None:
        return None
    mdir = Path(fid_dir) / "method"
    summ = read_json(mdir / "summary.json") or {}
    runs = _read_csv(mdir / "runs.csv")
    claims = _read_csv(Path(fid_dir) / "claims.csv")  # the level's verdicts with both methods' seed-1 ones
    done, _ = _runs_done(config, other, Path(fid_dir).parent)
    flows = [{"run": f["run"], "paper_pct": fmt(100 * f["paper"]), "accurate_pct": fmt(100 * f["accurate"])}
             for f in summ.get("flows", [])]
    compared = (claims["same_under_both_methods"] != "not compared"
                if claims is not None and "same_under_both_methods" in claims else None)
    png = mdir / "method_comparison.png"
    figure = _href(png, out_dir) if png.is_file() else None
    return {"is_accurate": False, "level": other, "planned": summ.get("accurate_runs_planned", 0), "done": done,
            "figure": figure,
            "pairs": summ.get("pairs", 0), "omega_compared": summ.get("omega_compared", 0),
            "omega_significant": summ.get("omega_significant", 0),
            "omega_median_pct": fmt(100 * float(summ.get("omega_median_abs_rel_diff", float("nan")))),
            "angle_compared": summ.get("angle_compared", 0), "angle_significant": summ.get("angle_significant", 0),
            "flows": flows, "claims_compared": summ.get("claims_compared", 0),
            "claims_changed": ", ".join(str(c) for c in summ.get("claims_changed", [])) or "none",
            "claims": table_of(claims[compared], ["claim", "verdict", "verdict_paper_method_seed1",
                                                   "verdict_accurate_method_seed1", "same_under_both_methods"])
            if compared is not None and compared.any() else None,
            "runs": table_of(runs, ["run", "observable", "paper", "paper_ci95", "accurate", "accurate_ci95", "rel_diff",
                                    "significant"]) if runs is not None and len(runs) else None}


def convergence_section(fid_dir: Path, fidelity: str, config: dict, out_dir: Path) -> dict | None:
    """The paper's observables by dx (``lbmpipe.reproduction.convergence``): the levels with their
    runs done and planned, the values, the observed orders and the figure of accuracy against cost
    (``results/<level>/convergence/``); None for a level nothing refines."""
    from .convergence import levels
    from .health import read_json

    lvls = levels(config, fidelity)
    if len(lvls) < 2:
        return None
    cdir = Path(fid_dir) / "convergence"
    summ = read_json(cdir / "summary.json") or {}
    vals, order = _read_csv(cdir / "values.csv"), _read_csv(cdir / "order.csv")
    info = []
    for lv in lvls:
        done, planned = _runs_done(config, lv, Path(fid_dir).parent)
        info.append({"level": lv, "dx": fmt(config["fidelities"][lv]["dx_mm"]), "done": done, "planned": planned})
    png = cdir / "accuracy_cost.png"
    figure = _href(png, out_dir) if png.is_file() else None
    return {"levels": info, "observed": summ.get("observed", 0), "compared": summ.get("compared", 0), "figure": figure,
            "order_table": table_of(order, list(order.columns)) if order is not None and len(order) else None,
            "value_table": table_of(vals, ["case", "observable", "dx_mm", "value", "ci95", "n_seeds", "loop_s_per_sim_s", "flags"])
            if vals is not None and len(vals) else None}


def _runs_done(config: dict, level: str, results_dir: Path) -> tuple[int, int]:
    """(completed, planned) runs of a level under ``results_dir``."""
    from .cases import level_runs
    from .health import read_json

    runs = level_runs(config, level)
    done = sum(1 for r in runs if (read_json(Path(results_dir) / level / "cases" / r / "summary.json") or {}).get("status")
               == "completed")
    return done, len(runs)


def health_section(fid_dir: Path, config: dict) -> dict:
    """Run health and diagnostics, one row per case (:func:`lbmpipe.reproduction.health.health_row`:
    from ``summary.json``, ``flow_rate.csv`` and ``stats.json``), thresholds from ``config.yaml``'s
    ``diagnostics`` block; the diagnostics of a ``stats.json`` written before they existed read
    "not computed"."""
    import pandas as pd

    from . import health

    diag = health.thresholds(config)
    rows, stale = [], []
    for name in config.get("cases") or {}:
        cdir = Path(fid_dir) / "cases" / name
        r = health.health_row(name, cdir, diag["health"])
        stats = health.read_json(cdir / "stats.json")
        if stats is not None and not health.health_is_computed(stats):
            stale.append(name)
            r.update(frozen="not computed", locked="not computed", steady="not computed")
        r["rotation_projection_share"] = r.pop("rotation_projection_share")
        r["flags"] = r["flags"].replace(";", ", ") or "none"
        rows.append(r)
    cols = ["case", "status", "mass_floor_rel", "mass_drift_rel", "mass_corrected_rel", "mass_corrected_throughflow",
            "density_deviation_median",
            "density_deviation_max", "rotation_projection_share", "max_overlap_lu", "max_overlap_between_lu",
            "flow_rate_error_rel", "frozen",
            "locked", "steady", "flags", "issues"]
    limits = ", ".join(f"`{k}` = {fmt(v)}" for k, v in diag["health"].items())
    intro = (f"Thresholds (`config.yaml`, `diagnostics`): {limits}; frozen beyond "
             f"{fmt(diag['frozen_remaining'])} of the orientation correlation with the packing left at the end, "
             f"locked when no pair passed and {fmt(diag['locked_neighbours_retained'])} of the nearest neighbours "
             f"are kept (or the bodies cannot sit side by side), spin-up at least "
             f"{fmt(diag['min_spinup_viscous_times'])} R²/ν. A case beyond a threshold is flagged in every table, "
             "figure and claim that uses it. `mass_corrected_rel` is – where `summary.json` does not record the "
             "mass correction.")
    note = (f"Frozen, locked and steady: {health.NOT_COMPUTED} ({', '.join(f'`{c}`' for c in stale)})."
            if stale else "")
    return {"table": table_of(pd.DataFrame(rows, columns=cols)), "intro": intro, "note": note, "rows": rows}


def stationarity_section(fid_dir: Path) -> dict | None:
    """How the runs' spin-up tests read at a family-wise 95 % (``steady.steady_corrected``): every
    run whose ``stats.json`` keeps the halves of its observables (``cases/*/seed*/`` or, one
    packing per case, ``cases/*/``); None when no run does."""
    from .health import read_json
    from .steady import steady_corrected

    cases = Path(fid_dir) / "cases"
    files = sorted(cases.glob("*/seed*/stats.json")) + sorted(cases.glob("*/stats.json"))
    runs = []
    for f in files:
        sp = (read_json(f) or {}).get("spinup") or {}
        if sp.get("observables"):
            runs.append({"run": str(f.parent.relative_to(cases)), **steady_corrected(sp)})
    if not runs:
        return None
    counts = {v: sum(r["verdict"] == v for r in runs) for v in ("steady", "drift", "mser", "chance", "no interval")}
    drift = [r["worst_z"] for r in runs if r["verdict"] == "drift"]
    ks = sorted({r["k"] for r in runs})
    return {"runs": runs, "n": len(runs), "counts": counts, "not_steady": len(runs) - counts["steady"],
            "k": "/".join(map(str, ks)), "bound": fmt(max(r["bound"] for r in runs)),
            "z_max": fmt(max(drift)) if drift else None,
            "mostly_drift": counts["drift"] + counts["mser"] > 2 * counts["chance"]}


def study_section(fid_dir: Path, out_dir: Path) -> dict:
    """The accuracy-cost study: its Markdown reports (``study/*.md``, generated from its CSVs), any
    CSV without a report as a table, and its figures."""
    sdir = Path(fid_dir) / "study"
    sec = {"present": sdir.is_dir(), "reports": [], "tables": [], "figures": []}
    if not sdir.is_dir():
        return sec
    mds = sorted(sdir.glob("*.md"))
    for md in mds:
        text = md.read_text(encoding="utf-8")
        # Demote the report's headings below the document's section level.
        text = re.sub(r"^(#+)", lambda m: "###" + m.group(1), text, flags=re.M)
        sec["reports"].append({"file": _rel(md, fid_dir), "text": text.strip()})
    covered = {md.stem for md in mds}
    for csv in sorted(sdir.glob("*.csv")):
        if csv.stem in covered:
            continue
        df = _read_csv(csv)
        if df is not None:
            sec["tables"].append({"file": _rel(csv, fid_dir), "table": table_of(df.head(60)),
                                  "truncated": len(df) > 60, "rows": fmt(len(df))})
    for png in sorted(sdir.glob("*.png")):
        sec["figures"].append({"file": _rel(png, fid_dir),
                               "image": _href(png, out_dir)})
    return sec


# --------------------------------------------------------------------------------------------------
# the paper-shaped document: key equations beside their code, one section per figure, the verdict

#: Key equations shown as display maths beside a short excerpt of the code: (equations, module,
#: qualname whose docstring cites them (the link), excerpt qualname, first line of the excerpt
#: (regex), number of lines). The excerpt may sit in a helper the cited definition calls.
KEY_EQUATIONS: list[tuple[tuple[int, ...], str, str, str, str, int]] = [
    ((8,), "lbmpipe/fluid/boundaries.py", "fill_moving_bounce_back", "fill_moving_bounce_back",
     r"for k in prange", 2),
    ((9, 10, 11, 12), "lbmpipe/particles/coupling/ladd.py", "fixed_fill", "fixed_fill", r"fx_ \+= 2\.0 \* ex \* sf", 6),
    ((13,), "lbmpipe/particles/rigid.py", "kick_angular_arrays", "kick_angular_arrays", r"tb = _rot\(", 4),
    ((14, 15), "lbmpipe/particles/rigid.py", "drift", "_free_rotate", r"ch = math\.cos\(0\.5", 6),
    ((19,), "lbmpipe/particles/collisions.py", "_gs_sweep", "_gs_sweep", r"vn = _normal_velocity\(i,", 6),
    ((21,), "lbmpipe/particles/collisions.py", "_wall_terms", "_wall_terms", r"a10, a11, a12, t1 = _body_terms", 6),
]

#: Which of the paper's claims each figure section discusses (NOTES.md: the claims and the figures they rest on).
FIGURE_CLAIMS: dict[str, list[int]] = {"4": [1, 3], "5": [4, 5], "6": [6], "7": [2, 7, 8], "8": [9, 10, 14],
                                       "9": [11, 12], "10": [13]}

#: Heading of each figure section (what the figure varies).
FIGURE_TITLES: dict[str, str] = {
    "4": "cylinder aspect ratio and rotation", "5": "cube concentration and rotation",
    "6": "Reynolds number and cube rotation", "7": "particle shape and size", "8": "cylinder orientation",
    "9": "cube orientation", "10": "velocity profile",
}


def display_latex(n: int) -> str:
    """The LaTeX of Eq. (n) for display: the formulas of :data:`EQUATIONS` joined by a wide space."""
    parts = re.findall(r"\$([^$]+)\$", EQUATIONS[n])
    return r",\qquad ".join(p.strip() for p in parts)


#: Labels of the key equations whose statement in :data:`EQUATIONS` ends without one.
EQUATION_LABELS: dict[int, str] = {
    3: "equilibrium distribution", 4: "density and momentum", 5: "weakly compressible Navier-Stokes: mass",
    6: "weakly compressible Navier-Stokes: momentum, viscosity", 14: "orientation as a unit quaternion (Evans 1977)",
    15: "quaternion kinematics", 16: "collision impulse: translation", 18: "collision impulse: rotation",
    19: "collision impulse of two particles", 20: "rotation matrix of the quaternion"}


def equation_label(n: int) -> str:
    """The closing parenthesis of :data:`EQUATIONS` (e.g. "Ladd's moving bounce-back"), else
    :data:`EQUATION_LABELS`, else ''."""
    m = re.search(r"\(([^()$]*)\)\s*$", EQUATIONS[n])
    return m.group(1) if m else EQUATION_LABELS.get(n, "")


def _def_node(tree: ast.Module, qualname: str):
    for qual, node, _ in _docstring_owners(tree):
        if qual == qualname:
            return node
    return None


def code_excerpt(repo_root: Path, module: str, qualname: str, start: str, n_lines: int) -> tuple[int, str] | None:
    """``n_lines`` lines of ``qualname`` in ``module`` from the first matching ``start`` (regex),
    dedented: (line number, text); None when the definition or the line is gone."""
    path = Path(repo_root) / module
    if not path.is_file():
        return None
    source = path.read_text(encoding="utf-8")
    node = _def_node(ast.parse(source), qualname)
    if node is None:
        return None
    lines = source.splitlines()
    for ln in range(node.lineno, node.end_lineno + 1):
        if re.search(start, lines[ln - 1]):
            chunk = lines[ln - 1: min(ln - 1 + n_lines, node.end_lineno)]
            indent = min(len(s) - len(s.lstrip()) for s in chunk if s.strip())
            return ln, "\n".join(s[indent:] for s in chunk)
    return None


def key_equations(repo_root: Path, out_dir: Path, index: dict[int, list[Ref]]) -> list[dict]:
    """Display maths, source link and code excerpt of each :data:`KEY_EQUATIONS` entry."""
    out = []
    for numbers, module, linked, excerpt_of, start, n_lines in KEY_EQUATIONS:
        refs = [r for n in numbers for r in index.get(n, []) if r.module == module and r.qualname == linked]
        ex = code_excerpt(repo_root, module, excerpt_of, start, n_lines)
        target = _href(Path(repo_root).resolve() / module, out_dir)
        out.append({
            "numbers": ", ".join(f"({n})" for n in numbers),
            "label": "; ".join(lb for lb in (equation_label(n) for n in numbers) if lb),
            "latex": [display_latex(n) for n in numbers],
            "link": _link(refs[0], numbers[0], repo_root, out_dir) if refs else None,
            "linked": linked,
            "excerpt": ex[1] if ex else None,
            "excerpt_link": f"[{module}:L{ex[0]}]({target}#L{ex[0]})" if ex else None,
            "excerpt_of": excerpt_of,
        })
    return out


def other_equations(groups: list[dict]) -> list[dict]:
    """The equations not in :data:`KEY_EQUATIONS`, each with its first source link (all links: the appendix)."""
    key = {n for entry in KEY_EQUATIONS for n in entry[0]}
    rows = []
    for g in groups:
        for eq in g["equations"]:
            if eq["number"] not in key:
                first = eq["links"][0]["link"] if eq["links"] else "**no docstring cites this equation**"
                rows.append({"number": eq["number"], "label": equation_label(eq["number"]), "link": first,
                             "more": len(eq["links"]) - 1})
    return rows


def main_text(md: str) -> str:
    """The document before its first appendix heading (``## Appendix ...``)."""
    m = re.search(r"^## Appendix", md, flags=re.M)
    return md[:m.start()] if m else md


def word_count(md: str) -> int:
    """Words of Markdown text: link targets and titles, image paths and table rules left out; a
    word is a whitespace-separated token with a letter or digit."""
    text = re.sub(r"\]\([^)]*\)", "]", md)
    return sum(1 for tok in text.split() if re.search(r"[A-Za-z0-9]", tok))


def _case_dirs(fid_dir: Path, config: dict) -> dict[str, dict]:
    """Per case of the config: its summary.json and stats.json (None where absent)."""
    from . import health

    out = {}
    for name in config.get("cases") or {}:
        cdir = Path(fid_dir) / "cases" / name
        out[name] = {"summary": health.read_json(cdir / "summary.json"), "stats": health.read_json(cdir / "stats.json")}
    return out


def averaging_s(summary: dict | None, stats: dict | None) -> float:
    """Simulated time averaged after spin-up of a case (s): run length minus spin-up; NaN if not run.
    A case combined over packings (``stats["seeds"]``): the mean over its packings of each one's."""
    if not summary or summary.get("status") != "completed":
        return float("nan")
    seeds = [x for x in (stats or {}).get("seeds") or [] if x.get("status") == "completed"]
    if seeds:
        spins = sum(float(x.get("spinup_s") or 0.0) for x in seeds)
        return (float(summary.get("simulated_seconds", float("nan"))) - spins) / len(seeds)
    spin = (stats or {}).get("spinup_s", summary.get("spinup_s", 0.0))
    spin = spin.get("spinup_s", 0.0) if isinstance(spin, dict) else spin
    return float(summary.get("simulated_seconds", float("nan"))) - float(spin or 0.0)


def _short_reason(reason: str) -> tuple[str, int]:
    """A claim's reason without its list of missing cases, and how many cases are missing."""
    parts = str(reason).split("; ")
    idx = next((k for k, p in enumerate(parts) if p.startswith("missing:")), len(parts))
    text = "; ".join(parts[:idx])
    if len(text) > 160:  # e.g. a list of bins per case: the appendix has it all
        text = text[:160].rsplit(",", 1)[0] + " … (appendix)"
    return text, len(parts) - idx


def _method_cell(r: dict) -> str:
    """``same``, ``changes: <paper> -> <accurate>`` or ``not compared`` (seed-1 verdicts)."""
    same = str(r.get("same_under_both_methods"))
    if same == "yes":
        return f"same ({r.get('verdict_paper_method_seed1')})"
    if same == "no":
        return f"changes: {r.get('verdict_paper_method_seed1')} -> {r.get('verdict_accurate_method_seed1')}"
    return "not compared"


def claims_summary(claims) -> list[dict]:
    """One row per claim: number, statement, verdict, the deciding number (the first clause of
    ``values``: the pooled difference or the single comparison) and the reason, shortened."""
    rows = []
    for r in claims.to_dict("records"):
        reason, n_missing = _short_reason(r.get("reason", ""))
        if n_missing:
            reason += f" ({n_missing} case{'s' if n_missing > 1 else ''} missing)"
        rows.append({"claim": fmt(r["claim"]), "statement": str(r.get("statement", "")),
                     "verdict": str(r.get("verdict", "")),
                     "number": str(r.get("values", "")).split("; ")[0].split(" over ")[0],
                     "reason": reason,
                     # the verdict under the accurate method (seed 1), where a level compares with this one
                     "method": _method_cell(r) if "same_under_both_methods" in r else None})
    return rows


def abstract_section(fid_dir: Path, fidelity: str, config: dict, claims, params: list[dict],
                     cases: dict[str, dict], health_rows: list[dict]) -> dict:
    """The verdict in numbers: claim counts, the particle-free flow against Hagen-Poiseuille, the
    lattice, the averaging time and the packings the results rest on."""
    counts = claims["verdict"].value_counts().to_dict() if claims is not None and "verdict" in claims else {}
    particle = [n for n, c in (config.get("cases") or {}).items() if (c or {}).get("particles")]
    flow = [n for n, c in (config.get("cases") or {}).items() if not (c or {}).get("particles")]
    poiseuille = [f"{fmt((config['cases'][n] or {}).get('reynolds'))}: "
                  f"{fmt(cases[n]['summary'].get('profile_error_rel_l2'))}"
                  for n in flow if cases.get(n, {}).get("summary")
                  and cases[n]["summary"].get("profile_error_rel_l2") is not None]
    avg = [averaging_s(cases[n]["summary"], cases[n]["stats"]) for n in particle if n in cases]
    avg = [a for a in avg if math.isfinite(a)]
    seeds = [int(s["n_seeds"]) for n in particle for s in [cases.get(n, {}).get("stats") or {}] if "n_seeds" in s]
    status = {}
    for n in particle:
        st = (cases.get(n, {}).get("summary") or {}).get("status", "not run")
        status[st] = status.get(st, 0) + 1
    lattice = [p for p in params if p["fidelity"] == fidelity]
    flagged = sum(1 for r in health_rows if r["flags"] not in ("none", ""))
    # resolution: lattice spacings across the smallest particle dimension of the level
    dx = ((config.get("fidelities") or {}).get(fidelity) or {}).get("dx_mm")
    dims = [float(v) for n in particle for k, v in ((config["cases"][n] or {}).get("particles") or {}).items()
            if k in ("diameter_mm", "length_mm", "edge_mm")]
    return {
        "n_claims": fmt(sum(counts.values())),
        "counts": ", ".join(f"{fmt(int(v))} {k}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1])),
        "poiseuille": "; ".join(f"Re {p}" for p in poiseuille),
        "lattice": "; ".join(f"Re {p['reynolds']}: dx {p['dx_mm']} mm, dt {p['dt_ms']} ms, τ {p['tau']}, "
                             f"Mach {p['mach']}" for p in lattice),
        "n_particle_cases": fmt(len(particle)),
        "status": ", ".join(f"{fmt(v)} {k}" for k, v in sorted(status.items(), key=lambda kv: -kv[1])),
        "avg_min": fmt(min(avg)) if avg else "–", "avg_max": fmt(max(avg)) if avg else "–",
        "avg_median": fmt(float(sorted(avg)[len(avg) // 2])) if avg else "–",
        "seeds": (f"{fmt(min(seeds))}–{fmt(max(seeds))}" if seeds and min(seeds) != max(seeds)
                  else fmt(seeds[0]) if seeds else None),
        "n_flagged": fmt(flagged), "n_health": fmt(len(health_rows)),
        "min_spacings": fmt(min(dims) / float(dx)) if dims and dx else None, "dx": fmt(dx),
    }


def _figure_case_names(key: str, av, config: dict) -> list[str]:
    """Cases a figure shows, by their metadata in ``angular_velocity.csv`` (the selections of
    :data:`lbmpipe.reproduction.figures.FIGURE_CASES`); Fig. 10 adds the particle-free flow, the figure
    of claim 14 the cases with collisions off."""
    from .figures import figure_cases

    names = figure_cases(av, key) if av is not None else []
    if key == "10":
        names += [n for n, c in (config.get("cases") or {}).items()
                  if not (c or {}).get("particles") and float((c or {}).get("reynolds", 0)) == 26.0]
    if 14 in FIGURE_CLAIMS.get(key, []):  # claim 14 compares with the same packing, collisions off
        names += [n for n, c in (config.get("cases") or {}).items()
                  if (c or {}).get("particles") and (c or {}).get("collisions") is False]
    return list(dict.fromkeys(names))


def _omega_line(row: dict) -> str:
    return (f"`{row['case']}` |Ω| x, y, z = {fmt(row['omega_x'])} ± {fmt(row['ci_x'])}, "
            f"{fmt(row['omega_y'])} ± {fmt(row['ci_y'])}, {fmt(row['omega_z'])} ± {fmt(row['ci_z'])} rad/s")


def first_sentence(text: str) -> str:
    """The first sentence of a caption (the rest stays in the figure files' captions)."""
    return re.split(r"(?<=\.)\s+(?=[A-Z])", text.strip(), maxsplit=1)[0]


def figure_sections(fid_dir: Path, out_dir: Path, config: dict, claims_rows: list[dict],
                    cases: dict[str, dict], health_rows: list[dict]) -> list[dict]:
    """One section per paper figure (Figs. 4-10): the paper's caption and claims, our figures with the
    numbers that decide (the bars of Figs. 4-6, the profile errors of Fig. 10, the deciding number
    of each claim), and why, from the measured diagnostics of the cases the figure shows."""
    fid_dir = Path(fid_dir)
    av = _read_csv(fid_dir / "tables" / "angular_velocity.csv")
    entries = figure_entries(fid_dir, out_dir)
    by_claim = {r["claim"]: r for r in claims_rows}
    health_by_case = {r["case"]: r for r in health_rows}
    out = []
    for key, title in FIGURE_TITLES.items():
        figs = [e for e in entries if e["key"] in (key, key + "a", key + "b")]
        names = _figure_case_names(key, av, config)
        numbers = []
        if key in ("4", "5", "6") and av is not None:
            numbers = [_omega_line(r) for r in av[av["case"].isin(names)].to_dict("records")]
        elif key == "10":
            numbers = [f"`{n}`: relative L2 difference from the Hagen-Poiseuille parabola "
                       f"{fmt(cases[n]['summary'].get('profile_error_rel_l2'))}"
                       for n in names if cases.get(n, {}).get("summary")]
        claims_here = [by_claim[fmt(c)] for c in FIGURE_CLAIMS.get(key, []) if fmt(c) in by_claim]
        # why: the flags and run-health issues measured for the cases of this figure
        why, not_computed = [], []
        for n in names:
            h = health_by_case.get(n)
            if h is None:
                continue
            if h["status"] not in ("completed",):
                why.append(f"`{n}` {h['status']}")
            elif h["flags"] not in ("none", ""):
                why.append(f"`{n}` {h['flags']}" + (f" ({h['issues']})" if h["issues"] else ""))
            if h.get("frozen") == "not computed":
                not_computed.append(n)
        avg = [averaging_s(cases[n]["summary"], cases[n]["stats"]) for n in names if n in cases]
        avg = [a for a in avg if math.isfinite(a)]
        out.append({
            "key": key, "title": title, "figures": figs,
            "paper_caption": PAPER_CAPTIONS.get(key, PAPER_CAPTIONS.get(key + "a", "")),
            "claims": claims_here, "numbers": numbers, "cases": names,
            "why": why, "n_clean": fmt(sum(1 for n in names if n in health_by_case) - len(why)),
            "not_computed": fmt(len(not_computed)) if not_computed else None,
            "avg": (f"{fmt(min(avg))}–{fmt(max(avg))}" if min(avg) != max(avg) else fmt(avg[0])) if avg else None,
            "diagnosed": [c for c in claims_here if "likely:" in c["reason"]],
        })
    return out


def health_summary_table(fid_dir: Path, config: dict, health_rows: list[dict], cases: dict[str, dict]) -> dict:
    """The run-health table of the main text: one row per case, short columns."""
    import pandas as pd

    pk = _read_csv(Path(fid_dir) / "tables" / "packing.csv")
    achieved = {} if pk is None else dict(zip(pk["case"], pk.get("concentration_achieved", [])))
    rows = []
    for r in health_rows:
        c = cases.get(r["case"], {})
        summ = c.get("summary") or {}
        ach = achieved.get(r["case"], (summ.get("particles") or {}).get("concentration_achieved"))
        rows.append({"case": r["case"], "status": r["status"],
                     "achieved (%)": 100 * ach if ach is not None else None,
                     "averaged (s)": averaging_s(summ, c.get("stats")),
                     "max abs(ρ-1)": r["density_deviation_max"], "flags": r["flags"]})
    return table_of(pd.DataFrame(rows))


def build_context(repo_root: Path, fid_dir: Path, fidelity: str, config: dict, out_md: Path) -> dict:
    """Everything the template shows, read from the results and the config (no literal numbers)."""
    repo_root, fid_dir, out_dir = Path(repo_root), Path(fid_dir), Path(out_md).parent
    groups, uncited = method_section(repo_root, out_dir)
    params, param_errors = parameter_rows(config)
    fids = config.get("fidelities") or {}
    decisions = []
    factors = sorted({fmt(f.get("re26_dt_factor", 1.0)) for f in fids.values()}) or ["1"]
    for title, text in DECISIONS:
        decisions.append({"title": title, "text": text.replace("{re26_dt_factors}", " / ".join(factors))})

    claims = _read_csv(fid_dir / "claims.csv")
    claims_ctx = None
    if claims is not None:
        counts = claims["verdict"].value_counts().to_dict() if "verdict" in claims else {}
        claims_ctx = {"table": table_of(claims, ["claim", "statement", "statistic", "values", "verdict", "reason"]),
                      "counts": [{"verdict": k, "n": fmt(int(v))} for k, v in sorted(counts.items())]}
        claims_ctx["counts_md"] = ", ".join(f"{c['n']} {c['verdict']}" for c in claims_ctx["counts"])
    fid_cfg = fids.get(fidelity, {})
    # A level on another level's lattice shows that level's stability suite and study (study_level).
    study_dir = fid_dir.parent / study_level(config, fidelity)
    stability = _read_csv(study_dir / "tables" / "stability.csv")
    health_ctx = health_section(fid_dir, config)
    case_data = _case_dirs(fid_dir, config)
    claim_rows = claims_summary(claims) if claims is not None else []
    particle_cases = [n for n, c in (config.get("cases") or {}).items() if (c or {}).get("particles")]
    from .figures import snapshot_gallery

    gallery = snapshot_gallery(fid_dir, particle_cases)  # Fig. 3: one tiled image of the snapshots
    return {
        "abstract": abstract_section(fid_dir, fidelity, config, claims, params, case_data, health_ctx["rows"]),
        "key_equations": key_equations(repo_root, out_dir, equation_index(repo_root / "lbmpipe")),
        "other_equations": other_equations(groups),
        "figure_sections": figure_sections(fid_dir, out_dir, config, claim_rows, case_data, health_ctx["rows"]),
        "claims_summary": claim_rows,
        "health_summary": health_summary_table(fid_dir, config, health_ctx["rows"], case_data),
        "gallery": _href(gallery, out_dir) if gallery else None,
        "gallery_caption": _our_caption("fig3_snapshot")[0],
        "level_parameters": [p for p in params if p["fidelity"] == fidelity],
        "fidelity": fidelity,
        "fid_dir": _rel_to(fid_dir, repo_root),
        # the paper's reading, relative to the document wherever it is built
        "reading_link": _href(repo_root.resolve() / "paper" / "reading.md", out_dir),
        "level_md": ", ".join(f"`{k}` = {fmt(v)}" for k, v in fid_cfg.items() if not isinstance(v, dict))
                    or "(not in config.yaml)",
        "level_run_md": ", ".join(f"`{k}` = {fmt(v)}" for k, v in (fid_cfg.get("run") or {}).items()) or "–",
        "equation_groups": groups,
        "uncited_equations": uncited,
        "parameters": params,
        "parameter_errors": param_errors,
        "cases": case_rows(config, fid_dir),
        "figures": figure_entries(fid_dir, out_dir),
        "decisions": decisions,
        "claims": claims_ctx,
        "stability": table_of(stability) if stability is not None else None,
        "study": study_section(study_dir, out_dir),
        "study_level": study_level(config, fidelity),
        "health": health_ctx,
        "runtime": runtime_section(fid_dir, fidelity),
        "method": method_comparison_section(fid_dir, fidelity, config, out_dir),
        "convergence": convergence_section(fid_dir, fidelity, config, out_dir),
        "stationarity": stationarity_section(fid_dir),
        "missing": lambda rel: f"not built at this level: `{_rel_to(fid_dir, repo_root)}/{rel}` missing",
    }


def study_level(config: dict, fidelity: str) -> str:
    """The level whose stability suite and accuracy-cost study a level's document shows: the
    level's ``study_level`` (a level on the same lattice), else the level itself."""
    return str(((config.get("fidelities") or {}).get(fidelity) or {}).get("study_level", fidelity))


def _rel_to(path: Path, root: Path) -> str:
    try:
        return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return Path(path).as_posix()


def build_document(repo_root: Path, fid_dir: Path, fidelity: str, config: dict, out_md: Path) -> Path:
    """Render ``paper/reproduction.md.j2`` for the results in ``fid_dir`` (``results/<fidelity>``)
    into ``out_md``, and its HTML beside it (``.html``). Links are relative to ``out_md``'s folder.
    Returns ``out_md``."""
    import jinja2

    repo_root, out_md = Path(repo_root), Path(out_md)
    out_md.parent.mkdir(parents=True, exist_ok=True)
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(repo_root / "paper")),
                             undefined=jinja2.StrictUndefined, keep_trailing_newline=True,
                             trim_blocks=True, lstrip_blocks=True, autoescape=False)
    env.filters["fmt"] = fmt
    env.filters["first_sentence"] = first_sentence
    text = env.get_template("reproduction.md.j2").render(**build_context(repo_root, fid_dir, fidelity, config, out_md))
    text = re.sub(r"\n{3,}", "\n\n", text)
    out_md.write_text(text, encoding="utf-8")
    from .webpage import markdown_to_html

    out_md.with_suffix(".html").write_text(markdown_to_html(text, title=f"lbmpipe reproduction ({fidelity})"),
                                           encoding="utf-8")
    return out_md


def build_checked_document(repo_root: Path, fidelity: str, config: dict,
                           out_md: Path | None = None) -> tuple[Path, list[str]]:
    """``build_document`` for ``results/<fidelity>`` under ``repo_root`` into ``out_md`` (default
    ``paper/reproduction_<fidelity>.md``), then ``check_links`` on it: the document and its stale
    links (empty when all are fresh). The pipeline's ``paper`` rule and ``lbmpipe document``."""
    repo_root = Path(repo_root)
    out_md = Path(out_md) if out_md is not None else repo_root / "paper" / f"reproduction_{fidelity}.md"
    out = build_document(repo_root, repo_root / "results" / fidelity, fidelity, config, out_md)
    return out, check_links(out, repo_root)
