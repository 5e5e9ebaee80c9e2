"""A user's first hour: ordinary mistakes at every entry point are answered by one line on stderr
that names the problem, with the documented exit code (docs/errors.md), never a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import marionette

URL = "udpm://239.255.76.67:7699?ttl=0"  # nothing listens there


def marionette_cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "marionette.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def controller(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(marionette.BUILD_DIR / "marionette-controller"), *args],
        capture_output=True,
        text=True,
        timeout=30,
    )


def _bad_problem(tmp: Path) -> str:
    path = tmp / "bad.yaml"
    path.write_text("name: bad\nrobots:\n  - robot: ur10\n   objects: [\n")
    return str(path)


def _bad_scene(tmp: Path) -> str:
    path = tmp / "bad_scene.yaml"
    path.write_text("format: marionette-scene 1\nname: bad_scene\nrobot: ur10\nobject: []\n")
    return str(path)


# (arguments, exit code, what the one line must contain); a callable argument gets tmp_path.
MISTAKES = [
    (["fsm", "inject", "abortt"], 2, "did you mean 'abort'"),
    (["demoo"], 2, "did you mean 'demo'"),
    (["demo", "ur10-bax"], 1, "did you mean 'ur10-box'"),
    (["demo", "ur10-box", "--trials", "0"], 2, "--trials"),
    (["--lcm-url", "garbage", "dg", "ls"], 2, "is not an LCM URL"),
    (["dg", "ls", "--lcm-url", "garbage"], 2, "is not an LCM URL"),
    (["view", "--lcm-url", "garbage", "--robot", "talos"], 2, "is not an LCM URL"),
    (["perceive", "--robot", "nosuch", "--max-frames", "1"], 1, "unknown robot 'nosuch'"),
    (["view", "--robot", "talos", "--scene", "models/scenes/nope.xml"], 1, "no scene file"),
    (["robot", "check", "nosuch"], 1, "unknown robot 'nosuch'"),
    (["robot", "check", "models"], 1, "no robot.yaml"),
    (["scene", "build", "models/scenes/nope.yaml"], 1, "no such file"),
    (["scene", "build", _bad_scene], 1, "unknown key 'object'; did you mean 'objects'"),
    (["calibrate", "arm-encoders", "--scene", "nope.xml"], 1, "no scene file"),
    (["footsteps", "plan", "--robot", "ur10"], 1, "two feet"),
    (["plan", "ur10_bx"], 1, "did you mean 'ur10_box'"),
    (["plan", _bad_problem], 1, "bad.yaml"),
    (["plan", "nope.yaml"], 1, "no problem file"),
    (["dg", "--timeout", "1", "ls", "--lcm-url", URL], 1, "no reply"),
    (["fsm", "--timeout", "1", "state", "--lcm-url", URL], 1, "is a supervisor running on"),
    (["fsm", "--timeout", "1", "events", "--lcm-url", URL], 1, "is a supervisor running on"),
    (["demo", _bad_problem], 1, "bad.yaml:4: not valid YAML"),
    (["perceive", "--lcm-url", "garbage", "--robot", "talos"], 2, "is not an LCM URL"),
    (["supervise", "nope.json"], 1, "nope.json"),
    (["replay", "nope.lcmlog", "--view"], 1, "no LCM log at nope.lcmlog"),
    (["replay", "nope.lcmlog", "--supervisor"], 1, "nope.lcmlog"),
    (["demo", "ur10-box", "--perturb", "nosuch"], 2, "nosuch"),
    (["demo", "ur10-box", "--perturb", "nope.yaml"], 1, "nope.yaml"),
    (["robot", "import", "nope.urdf", "--name", "x"], 1, "nope.urdf"),
    (["footsteps", "run", "--lcm-url", "garbage"], 2, "is not an LCM URL"),
    *(
        (["footsteps", "plan", "--mode", "step-over", "--crossing-duration", v], 1, "> 0 s")
        for v in ("-1", "0", "nan", "inf")
    ),
    *(
        (["perceive", "--robot", "none", "--max-position-sigma", v], 2, "positive number")
        for v in ("-1", "0", "nan", "inf")
    ),
    *(
        (
            ["perceive", "--robot", "none", "--up-axis", "bar:0,0,1", "--max-tilt-deg", v],
            2,
            "(0, 180)",
        )
        for v in ("-1", "0", "nan", "180")
    ),
    (["perceive", "--robot", "none", "--max-tilt-deg", "5"], 2, "needs --up-axis"),
]


@pytest.mark.parametrize(("args", "code", "text"), MISTAKES, ids=lambda v: str(v)[:40])
def test_a_mistake_gets_one_line_and_its_exit_code(tmp_path, args, code, text):
    args = [a(tmp_path) if callable(a) else a for a in args]
    proc = marionette_cli(*args)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == code, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    assert len(lines) == 1 and text in lines[0], proc.stderr


@pytest.mark.parametrize(
    ("args", "code", "text"),
    [
        (["--robot", "nosuch", "--describe-robot"], 1, "unknown robot 'nosuch'"),
        (["--robot", "talos", "--bogus"], 2, "unknown argument '--bogus'"),
        (["--describe-robot"], 2, "--robot NAME|DIR is required"),
        (["--robot", "talos", "--lcm-url", "garbage", "--duration", "0.1"], 2, "not an LCM URL"),
    ],
)
def test_the_controller_answers_in_one_line(args, code, text):
    proc = controller(*args)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == code, proc.stderr
    assert len(lines) == 1 and text in lines[0], proc.stderr


def test_every_help_page_has_an_example():
    from marionette.cli import build_parser

    parser = build_parser()
    pages = [("marionette", parser)]
    actions = [
        a for a in parser._actions if isinstance(a, type(parser._subparsers._group_actions[0]))
    ]
    for action in actions:
        for name, sub in action.choices.items():
            pages.append((f"marionette {name}", sub))
    missing = [name for name, p in pages if "example" not in (p.epilog or "")]
    assert not missing, f"--help pages without an example: {missing}"


TOOLS = sorted(
    str(p.relative_to(marionette.REPO_ROOT))
    for folder in ("scripts", "bench")
    for p in (marionette.REPO_ROOT / folder).iterdir()
    if p.is_file() and os.access(p, os.X_OK)
)


@pytest.mark.parametrize("tool", TOOLS)
def test_every_script_and_benchmark_answers_help_without_running(tool):
    """`--help` prints what the tool does and exits 0 at once: it neither runs the benchmark nor
    sets anything up (a benchmark once ran, and the set-up once built, on `--help`)."""
    proc = subprocess.run(
        [str(marionette.REPO_ROOT / tool), "--help"],
        capture_output=True,
        text=True,
        timeout=30,
        env={
            **os.environ,
            "PATH": f"{marionette.REPO_ROOT / '.venv' / 'bin'}:{os.environ['PATH']}",
        },
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip(), "no help text"
    assert "[setup]" not in proc.stdout and "[bench]" not in proc.stdout, proc.stdout
