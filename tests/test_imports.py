"""The package's layout: no import loop among lbmpipe's modules, no module over 800 lines, and a
function-level import of the package's own modules only with a reason written beside it.

The imports are read from the sources with ``ast`` (nothing is imported): imports inside functions
count, relative imports are resolved against the importing module, and ``from pkg import name``
counts as importing ``pkg.name`` when that is a module, else ``pkg``.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = "lbmpipe"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE
MAX_LINES = 800
#: a function-level import of the package must say why on its line or the line above
REASON_TAGS = ("# heavy:", "# optional:")


def _modules() -> dict[str, Path]:
    """Dotted module name -> source file, for every module of the package."""
    mods = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = path
    return mods


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _imports(name: str, path: Path, modules: dict[str, Path]):
    """(imported module, line number, inside a function) for every import of the package's own
    modules in ``name``'s source."""
    tree = ast.parse(path.read_text(), filename=str(path))
    base = name.split(".") if _is_package(path) else name.split(".")[:-1]
    found = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            fn = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.name.split(".")[0] == PACKAGE:
                        found.append((_known(alias.name, modules), child.lineno, in_function))
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    anchor = base[: len(base) - (child.level - 1)]
                    target = ".".join(anchor + ([child.module] if child.module else []))
                else:
                    target = child.module or ""
                if target.split(".")[0] == PACKAGE:
                    for alias in child.names:
                        sub = f"{target}.{alias.name}"
                        found.append((sub if sub in modules else _known(target, modules), child.lineno,
                                      in_function))
            visit(child, fn)

    visit(tree, False)
    return [f for f in found if f[0] is not None and f[0] != name]


def _known(dotted: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of ``dotted`` that is a module of the package."""
    parts = dotted.split(".")
    while parts:
        if ".".join(parts) in modules:
            return ".".join(parts)
        parts.pop()
    return None


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (anywhere in its source)."""
    modules = _modules()
    return {name: {m for m, _, _ in _imports(name, path, modules)} for name, path in modules.items()}


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component of more than one module (or a self-loop),
    as a closed path ``[a, b, ..., a]`` (Tarjan's algorithm, then a path inside the component)."""
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            comps.append(set(comp))

    import sys
    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                strong(v)
    finally:
        sys.setrecursionlimit(limit)

    cycles = []
    for comp in comps:
        start = min(comp)
        if len(comp) == 1 and start not in graph.get(start, ()):
            continue
        # breadth-first from start back to start inside the component: the shortest loop through it
        prev, frontier, done = {}, [start], None
        while frontier and done is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph.get(v, ())):
                    if w not in comp:
                        continue
                    if w == start:
                        done = v
                        break
                    if w not in prev:
                        prev[w] = v
                        nxt.append(w)
                if done is not None:
                    break
            frontier = nxt
        path = [start]
        v = done
        while v != start:
            path.append(v)
            v = prev[v]
        path.append(start)
        path = [path[0]] + path[1:-1][::-1] + [start]
        cycles.append(path)
    return cycles


def tangle(graph: dict[str, set[str]], start: str) -> set[str]:
    """The modules that ``start`` reaches and that reach it back (its strongly connected component)."""
    def reach(g, v):
        seen, todo = {v}, [v]
        while todo:
            for w in g.get(todo.pop(), ()):
                if w not in seen:
                    seen.add(w)
                    todo.append(w)
        return seen
    back = {}
    for v, ws in graph.items():
        for w in ws:
            back.setdefault(w, set()).add(v)
    return reach(graph, start) & reach(back, start)


def test_find_cycles_reports_a_loop_and_passes_a_tree():
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert find_cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_relative_and_from_package_imports_resolve_to_modules(tmp_path):
    modules = {"lbmpipe": tmp_path / "__init__.py", "lbmpipe.x": tmp_path / "x.py",
               "lbmpipe.sub": tmp_path / "sub" / "__init__.py", "lbmpipe.sub.y": tmp_path / "sub" / "y.py"}
    src = tmp_path / "sub" / "y.py"
    src.parent.mkdir()
    src.write_text("from .. import x\nfrom . import y\ndef f():\n    from ..x import thing\n")
    got = _imports("lbmpipe.sub.y", src, modules)
    assert ("lbmpipe.x", 1, False) in got and ("lbmpipe.x", 4, True) in got


def test_no_import_loop_among_the_package_modules():
    graph = import_graph()
    cycles = find_cycles(graph)
    assert not cycles, "import loops (imports inside functions included), one per tangle:\n" + "\n".join(
        " -> ".join(c) + f"  (tangle of {len(tangle(graph, c[0]))} modules: {', '.join(sorted(tangle(graph, c[0])))})"
        for c in cycles)


def test_no_module_over_800_lines():
    long = {name: len(path.read_text().splitlines()) for name, path in _modules().items()}
    long = {k: v for k, v in long.items() if v > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: " + ", ".join(f"{k} ({v})" for k, v in sorted(long.items()))


def test_function_level_imports_of_the_package_say_why():
    modules = _modules()
    bare = []
    for name, path in modules.items():
        lines = path.read_text().splitlines()
        for target, lineno, inside in _imports(name, path, modules):
            if not inside:
                continue
            near = lines[lineno - 1] + "\n" + (lines[lineno - 2] if lineno >= 2 else "")
            if not any(tag in near for tag in REASON_TAGS):
                bare.append(f"{path.relative_to(ROOT.parent)}:{lineno} imports {target}")
    assert not bare, ("function-level imports of the package's own modules without a reason "
                      f"({' or '.join(REASON_TAGS)} on the line or the line above):\n" + "\n".join(sorted(set(bare))))
