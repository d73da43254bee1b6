"""The paper's equations and where the code implements them.

Docstrings cite the paper's equations by number (``Eq. (N)``, ``Eqs. (N)-(M)``, ``Eqs. (N), (M)``,
``Eq. (N, M)``); :func:`equation_index` reads them with :mod:`ast` (module, class and function
docstrings of ``lbmpipe/**/*.py``), so the index is the code's own statement of where each
equation lives and cannot drift from it. Each link in the document carries a title
``"Eq. N: qualname"`` that :func:`check_links` uses to verify that the line still holds that
definition and that its docstring still cites the equation. :data:`KEY_EQUATIONS` are the
equations the document displays beside a short excerpt of their code (:func:`key_equations`).
"""

from __future__ import annotations

import ast
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


def relative_href(target: Path, out_dir: Path) -> str:
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


def equation_link(ref: Ref, eq: int, repo_root: Path, out_dir: Path) -> str:
    target = relative_href(Path(repo_root).resolve() / ref.module, out_dir)
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


#: Key equations shown as display maths beside a short excerpt of the code: (equations, module,
#: qualname whose docstring cites them (the link), excerpt qualname, first line of the excerpt
#: (regex), number of lines). The excerpt may sit in a helper the cited definition calls.
KEY_EQUATIONS: list[tuple[tuple[int, ...], str, str, str, str, int]] = [
    ((8,), "lbmpipe/fluid/boundaries.py", "fill_moving_bounce_back", "fill_moving_bounce_back",
     r"for k in prange", 2),
    ((9, 10, 11, 12), "lbmpipe/particles/coupling/ladd.py", "fixed_fill", "fixed_fill", r"fx_ \+= 2\.0 \* ex \* sf", 6),
    ((13,), "lbmpipe/particles/rigid.py", "kick_angular_arrays", "kick_angular_arrays", r"tb = _rot\(", 4),
    ((14, 15), "lbmpipe/particles/rigid.py", "drift", "_free_rotate", r"ch = math\.cos\(0\.5", 6),
    ((19,), "lbmpipe/particles/collisions/impulse.py", "_gs_sweep", "_gs_sweep", r"vn = _normal_velocity\(i,", 6),
    ((21,), "lbmpipe/particles/collisions/impulse.py", "_wall_terms", "_wall_terms", r"a10, a11, a12, t1 = _body_terms", 6),
]


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
        target = relative_href(Path(repo_root).resolve() / module, out_dir)
        out.append({
            "numbers": ", ".join(f"({n})" for n in numbers),
            "label": "; ".join(lb for lb in (equation_label(n) for n in numbers) if lb),
            "latex": [display_latex(n) for n in numbers],
            "link": equation_link(refs[0], numbers[0], repo_root, out_dir) if refs else None,
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
