"""Robots are data: no robot found in models/ is named by the code that runs — its identifiers
and string literals — in C++ or in the Python package. Comments, docstrings and the examples of
``--help`` pages may cite a robot; the scenario declarations pick a robot for an experiment."""

from __future__ import annotations

import ast
import re

from marionette import REPO_ROOT, robots

ALLOWED = ("python/marionette/scenarios/",)  # experiments name the robot they run
PROSE_KEYWORDS = {"help", "epilog", "description"}  # argparse text shown to users


class _RobotWord:
    """A robot's name as a word: in snake_case, CamelCase (LoadTalos) or prose."""

    def __init__(self, names):
        alternatives = "|".join(map(re.escape, names))
        self._re = re.compile(r"(?<![a-z0-9])(" + alternatives + r")(?![a-z0-9])", re.I)

    def search(self, text: str):
        return self._re.search(re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", text))


def _cpp_code(text: str) -> str:
    """The C++ / CMake source without its comments (string literals kept)."""
    token = re.compile(r'"(?:\\.|[^"\\\n])*"|//[^\n]*|/\*.*?\*/|#[^\n]*', re.S)

    def keep(m: re.Match) -> str:
        t = m.group(0)
        if t.startswith('"') or (t.startswith("#") and re.match(r"#\s*include", t)):
            return t
        if t.startswith("#") and not m.string.endswith(".txt"):
            return t  # a preprocessor line
        return "\n" * t.count("\n")

    return token.sub(keep, text)


def _cmake_code(text: str) -> str:
    return re.sub(r"#[^\n]*", "", text)


def _python_code_strings(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, text) of every identifier and string literal that is not prose."""
    prose: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            if isinstance(body[0].value, ast.Constant):
                prose.add(id(body[0].value))  # docstring
        if isinstance(node, ast.keyword) and node.arg in PROSE_KEYWORDS:
            prose.update(id(n) for n in ast.walk(node.value))
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id.endswith("EXAMPLES") for t in node.targets
        ):
            prose.update(id(n) for n in ast.walk(node.value))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in prose:
            found.append((node.lineno, node.value))
        elif isinstance(node, ast.Name):
            found.append((node.lineno, node.id))
        elif isinstance(node, ast.Attribute):
            found.append((node.lineno, node.attr))
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            found.append((node.lineno, node.name))
        elif isinstance(node, ast.arg):
            found.append((node.lineno, node.arg))
    return found


def test_no_robot_is_named_in_the_code():
    names = robots.robot_names()
    assert len(names) >= 3
    pattern = _RobotWord(names)
    hits = []
    for path in (REPO_ROOT / "cpp").rglob("*"):
        if path.suffix not in (".cc", ".h") and path.name != "CMakeLists.txt":
            continue
        text = path.read_text(errors="replace")
        code = _cmake_code(text) if path.name == "CMakeLists.txt" else _cpp_code(text)
        for n, line in enumerate(code.splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{path.relative_to(REPO_ROOT)}:{n}: {line.strip()[:90]}")
    for path in (REPO_ROOT / "python" / "marionette").rglob("*.py"):
        rel = path.relative_to(REPO_ROOT).as_posix()
        if rel.startswith(ALLOWED):
            continue
        for line, text in _python_code_strings(ast.parse(path.read_text(), rel)):
            if pattern.search(text):
                hits.append(f"{rel}:{line}: {text.strip()[:90]!r}")
    assert not hits, f"{len(hits)} places name a robot:\n" + "\n".join(sorted(hits)[:40])


def test_the_check_sees_code_and_spares_prose():
    """The two filters above, on a known sample: a literal and an identifier are found; a
    comment, a docstring and a help example are not."""
    pattern = _RobotWord(["talos"])
    cpp = '// TALOS has two arms\nauto m = LoadTalos(); /* talos */\nconst char* s = "talos";\n'
    assert [n for n, l in enumerate(_cpp_code(cpp).splitlines(), 1) if pattern.search(l)] == [2, 3]
    py = (
        '"""TALOS."""\nimport argparse\n# talos\n'
        'p = argparse.ArgumentParser(epilog="marionette demo --robot talos")\n'
        'def load_talos(): return "talos"\n'
    )
    assert sorted(n for n, t in _python_code_strings(ast.parse(py)) if pattern.search(t)) == [5, 5]
