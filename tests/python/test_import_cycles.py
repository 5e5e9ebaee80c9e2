"""No import cycle in the ``marionette`` package: the module graph is built from the source (every
``import`` and ``from ... import`` statement, those inside functions included, as a deferred import
only postpones a cycle; only the ``if TYPE_CHECKING:`` blocks are left out, as they never run),
and a strongly connected component of more than one module fails the test with one cycle of it
spelled out."""

from __future__ import annotations

import ast
from pathlib import Path

import marionette

PACKAGE_DIR = Path(marionette.__file__).resolve().parent


def module_name(path: Path, root: Path) -> str:
    """``marionette.a.b`` of ``root/marionette/a/b.py`` (of a package's ``__init__.py``: the
    package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def import_statements(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of ``tree`` at any depth, except under ``if TYPE_CHECKING:``."""
    out: list[ast.Import | ast.ImportFrom] = []
    todo: list[ast.AST] = [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append(node)
        elif isinstance(node, ast.If) and _is_type_checking(node.test):
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))
    return out


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Module -> the modules of the same package it imports (anywhere in its body)."""
    root = package_dir.parent
    files = {module_name(p, root): p for p in sorted(package_dir.rglob("*.py"))}
    graph: dict[str, set[str]] = {m: set() for m in files}

    def known(name: str) -> str | None:
        """``name`` or its longest prefix that is a module of the package."""
        while name:
            if name in files:
                return name
            name = name.rpartition(".")[0]
        return None

    for module, path in files.items():
        is_package = path.name == "__init__.py"
        for node in import_statements(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:  # relative: from the module's package, up level - 1
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    source = ".".join(base + ([node.module] if node.module else []))
                else:
                    source = node.module or ""
                # `from a import b`: the submodule a.b when there is one, else a's attribute b
                targets = [
                    f"{source}.{a.name}" if f"{source}.{a.name}" in files else source
                    for a in node.names
                ]
            for t in targets:
                target = known(t)
                if target is not None and target != module:
                    graph[module].add(target)
    return graph


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative), each as a list of modules."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    out.append(sorted(component))
    return out


def a_cycle(graph: dict[str, set[str]], component: list[str]) -> list[str]:
    """One cycle through the first module of a strongly connected ``component``:
    a shortest path back to it (breadth first inside the component)."""
    inside = set(component)
    start = component[0]
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & inside):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return [start, *reversed(path[:-1]), start]
                if w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"{component} is not strongly connected")


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    return [a_cycle(graph, c) for c in strongly_connected(graph) if len(c) > 1]


def test_the_package_has_no_import_cycle():
    found = cycles(import_graph(PACKAGE_DIR))
    assert not found, "import cycles in marionette:\n" + "\n".join(" -> ".join(c) for c in found)


def test_the_graph_sees_deferred_and_relative_imports_and_names_the_cycle(tmp_path):
    """The checker on a package written here: a cycle closed by an import inside a function and
    a relative import is found and named; submodule and attribute imports resolve apart."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from pkg.sub.leaf import VALUE\n")
    (pkg / "sub" / "leaf.py").write_text("VALUE = 1\n")
    (pkg / "a.py").write_text("from pkg import b\n")
    (pkg / "b.py").write_text("def f():\n    from .c import g\n    return g\n")
    (pkg / "c.py").write_text(
        "import os\nfrom typing import TYPE_CHECKING\nfrom pkg.sub import VALUE\n\n"
        "if TYPE_CHECKING:\n    from pkg import d\nelse:\n    from pkg import e\n\n"
        "def g():\n    import pkg.a\n"
    )
    (pkg / "d.py").write_text("import pkg.c\n")
    (pkg / "e.py").write_text("")
    graph = import_graph(pkg)
    assert graph["pkg.a"] == {"pkg.b"}
    assert graph["pkg.b"] == {"pkg.c"}
    assert graph["pkg.c"] == {"pkg.sub", "pkg.a", "pkg.e"}  # not pkg.d: type checking only
    assert graph["pkg.sub"] == {"pkg.sub.leaf"}
    assert cycles(graph) == [["pkg.a", "pkg.b", "pkg.c", "pkg.a"]]
    (pkg / "c.py").write_text("from pkg.sub import VALUE\n")
    assert cycles(import_graph(pkg)) == []


def test_tarjan_agrees_with_brute_force_reachability_on_random_graphs():
    """Components against the definition: v and w in one component iff each reaches the other
    (transitive closure by repeated squaring of the adjacency, written here)."""
    import numpy as np

    rng = np.random.default_rng(0)
    for _ in range(200):
        n = int(rng.integers(1, 12))
        adjacency = rng.uniform(size=(n, n)) < rng.uniform(0.05, 0.4)
        np.fill_diagonal(adjacency, False)
        graph = {str(i): {str(j) for j in range(n) if adjacency[i, j]} for i in range(n)}
        reach = adjacency | np.eye(n, dtype=bool)
        for _ in range(n):
            reach = reach | ((reach.astype(int) @ reach.astype(int)) > 0)
        mutual = reach & reach.T
        expected = sorted(sorted(str(j) for j in range(n) if mutual[i, j]) for i in range(n))
        got = sorted(strongly_connected(graph))
        assert sorted({tuple(c) for c in expected}) == sorted(tuple(c) for c in got)
        for c in cycles(graph):  # each named cycle is one: consecutive edges, closed
            assert c[0] == c[-1] and all(b in graph[a] for a, b in zip(c, c[1:]))
