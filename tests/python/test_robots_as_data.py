"""Robots are data: no robot found in models/ is named in the C++ code, nor in the Python package
outside the scenario declarations (which pick a robot for an experiment) and its data files."""

from __future__ import annotations

import re

from marionette import REPO_ROOT, robots

ALLOWED = ("python/marionette/scenarios/",)  # experiments name the robot they run


def _named(paths, names) -> list[str]:
    pattern = re.compile(r"\b(" + "|".join(map(re.escape, names)) + r")\b", re.IGNORECASE)
    hits = []
    for path in paths:
        rel = path.relative_to(REPO_ROOT).as_posix()
        if rel.startswith(ALLOWED):
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if pattern.search(line):
                hits.append(f"{rel}:{n}: {line.strip()[:90]}")
    return hits


def test_no_robot_is_named_in_the_code():
    names = robots.robot_names()
    assert len(names) >= 3
    code = [
        *(p for p in (REPO_ROOT / "cpp").rglob("*") if p.suffix in (".cc", ".h", ".txt")),
        *(REPO_ROOT / "python" / "marionette").rglob("*.py"),
    ]
    hits = _named(code, names)
    assert not hits, f"{len(hits)} lines name a robot:\n" + "\n".join(hits[:40])
