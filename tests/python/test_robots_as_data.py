"""Robots are data: no robot found in models/ is named in the C++ sources (comments included),
nor by the Python package's code — its identifiers and string literals. Python comments,
docstrings and the examples of ``--help`` pages may cite a robot; the scenario declarations pick
a robot for an experiment."""

from __future__ import annotations

import ast
import re

import pytest

from marionette import REPO_ROOT, robots

# Experiments name the robot they run: the scenarios and the benchmarks.
ALLOWED = ("python/marionette/scenarios/",)
EXPERIMENT = re.compile(r"(^|_)bench(mark)?(_|\.py$)")
PROSE_KEYWORDS = {"help", "epilog", "description"}  # argparse text shown to users


class _RobotWord:
    """A robot's name as a word: in snake_case, CamelCase (LoadTalos) or prose."""

    def __init__(self, names):
        alternatives = "|".join(map(re.escape, names))
        self._re = re.compile(r"(?<![a-z0-9])(" + alternatives + r")(?![a-z0-9])", re.I)

    def search(self, text: str):
        return self._re.search(re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", text))


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


@pytest.mark.slow
def test_no_robot_is_named_in_the_code():
    names = robots.robot_names()
    assert len(names) >= 3
    pattern = _RobotWord(names)
    hits = []
    for path in (REPO_ROOT / "cpp").rglob("*"):
        if path.suffix not in (".cc", ".h") and path.name != "CMakeLists.txt":
            continue
        # C++: not even a comment (a cost example speaks of "a humanoid", not of a product).
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{path.relative_to(REPO_ROOT)}:{n}: {line.strip()[:90]}")
    for path in (REPO_ROOT / "python" / "marionette").rglob("*.py"):
        rel = path.relative_to(REPO_ROOT).as_posix()
        if rel.startswith(ALLOWED) or EXPERIMENT.search(path.name):
            continue
        for line, text in _python_code_strings(ast.parse(path.read_text(), rel)):
            if pattern.search(text):
                hits.append(f"{rel}:{line}: {text.strip()[:90]!r}")
    assert not hits, f"{len(hits)} places name a robot:\n" + "\n".join(sorted(hits)[:40])


def test_the_check_sees_code_and_spares_prose():
    """The word match and the Python filter on a known sample: a literal and an identifier are
    found; a comment, a docstring and a help example are not."""
    pattern = _RobotWord(["talos"])
    assert pattern.search("auto m = LoadTalos();") and not pattern.search("Italos")
    py = (
        '"""TALOS."""\nimport argparse\n# talos\n'
        'p = argparse.ArgumentParser(epilog="marionette demo --robot talos")\n'
        'def load_talos(): return "talos"\n'
    )
    assert sorted(n for n, t in _python_code_strings(ast.parse(py)) if pattern.search(t)) == [5, 5]


def test_the_controller_is_given_the_robot_folder_python_found(tmp_path, monkeypatch):
    """The compiled controller searches the models/ of the checkout it was built in: a robot
    found by this Python elsewhere (another worktree sharing a build, $MARIONETTE_ROBOT_PATH
    set for Python only) reached it by name as unknown or, worse, as another robot of that name.
    Every controller command line gives the folder Python found."""
    import shutil

    from marionette.scenarios.harness import Processes, controller_command

    name = robots.robot_names()[0]
    source = robots.robot(name).directory
    folder = tmp_path / "models" / name  # this checkout's models/, not the controller's
    shutil.copytree(source, folder, symlinks=True)
    monkeypatch.setattr(robots, "MODELS_DIR", tmp_path / "models")
    command = controller_command(Processes(name, tmp_path / "s.xml"), "u", 0.0)
    argument = command[command.index("--robot") + 1]
    assert argument == str(folder.resolve()), argument
    assert robots.controller_robot_argument(str(folder)) == str(folder.resolve())
