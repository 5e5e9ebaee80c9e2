"""``marionette robot list|check|import`` and ``marionette scene build``: robots and scenes as
data (docs/robots.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROBOT_EXAMPLES = """examples:
  marionette robot list
  marionette robot import $(python -m cmeel
  cmake)/share/example-robot-data/robots/panda_description/urdf/panda.urdf \\
      --srdf .../panda_description/srdf/panda.srdf --name panda --out models/panda
  marionette robot check models/panda
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "robot",
        help="list, check or import a robot described by data (URDF + SRDF + robot.yaml)",
        description="Robots are folders of data: URDF, SRDF and robot.yaml (docs/robots.md).",
        epilog=ROBOT_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="robot_command", required=True, metavar="ACTION")
    ls = sub.add_parser("list", help="the robots found (models/ and $MARIONETTE_ROBOT_PATH)")
    ls.set_defaults(func=_list)
    check = sub.add_parser(
        "check",
        help="validate a robot folder, say what to fix, then write and compile its MJCF",
        epilog="example:\n  marionette robot check models/panda",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    check.add_argument("robot", help="robot folder (or a name found on the robot search path)")
    check.add_argument("--no-build", action="store_true", help="check only; write no MJCF")
    check.set_defaults(func=_check)
    imp = sub.add_parser(
        "import",
        help="start a robot folder from a URDF (and SRDF): files and a robot.yaml to review",
        epilog=ROBOT_EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    imp.add_argument("urdf", type=Path, help="the robot's URDF (xacro expanded)")
    imp.add_argument("--name", required=True, help="robot name: lower case, digits, _")
    imp.add_argument("--out", type=Path, default=None, help="robot folder (default models/NAME)")
    imp.add_argument("--srdf", type=Path, default=None, help="its SRDF (default: one is written)")
    imp.add_argument(
        "--base", choices=("fixed", "free_flyer", "planar"), default="fixed", help="root joint"
    )
    imp.add_argument("--gripper-link", default=None, help="link carrying the gripper frame")
    imp.set_defaults(func=_import)

    s = subparsers.add_parser(
        "scene",
        help="build a scene's MuJoCo model from its YAML",
        epilog="example:\n  marionette scene build models/scenes/panda_cube.yaml",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ssub = s.add_subparsers(dest="scene_command", required=True, metavar="ACTION")
    build = ssub.add_parser("build", help="write <scene>.xml beside <scene>.yaml")
    build.add_argument("scene", type=Path, help="scene declaration (YAML)")
    build.set_defaults(func=_build_scene)


def _list(args: argparse.Namespace) -> int:
    from marionette import robots

    for name in robots.robot_names():
        d = robots.robot(name)
        print(f"{name:12s} {d.base:10s} {d.directory}")
    return 0


def _check(args: argparse.Namespace) -> int:
    from marionette.models.robot_check import NOT_COMPILED, check_robot

    findings = check_robot(args.robot, build=not args.no_build)
    for f in findings:
        print(f, file=sys.stderr if f.level == "error" else sys.stdout)
    errors = sum(f.level == "error" for f in findings)
    if errors:
        print(f"{args.robot}: {errors} problem(s) to fix")
        return 1
    built = not args.no_build
    compiled = built and not any(f.message == NOT_COMPILED for f in findings)
    print(
        f"{args.robot}: ok"
        + (" (MJCF written and compiled)" if compiled else " (MJCF written)" if built else "")
    )
    return 0


def _import(args: argparse.Namespace) -> int:
    import marionette
    from marionette.models.robot_import import RobotImportError, import_robot

    out = args.out or (marionette.MODELS_DIR / args.name)
    try:
        notes = import_robot(args.urdf, args.name, out, args.srdf, args.base, args.gripper_link)
    except RobotImportError as e:
        print(f"marionette robot import: {e}", file=sys.stderr)
        return 1
    print(f"wrote {out}: {args.name}.urdf, {args.name}.srdf, robot.yaml; review:")
    for n in notes:
        print(f"  - {n}")
    print(f"then: marionette robot check {out}")
    return 0


def _build_scene(args: argparse.Namespace) -> int:
    from marionette import robots
    from marionette.models.mjcf import RobotModelError
    from marionette.models.scenes import load_scene, scene_mjcf
    from marionette.schemas import DataFileError

    try:
        scene = load_scene(args.scene)
        q = robots.reference_configuration(scene.robot)
        text = scene_mjcf(scene, q)
    except (DataFileError, robots.UnknownModel, RobotModelError, ValueError, KeyError) as e:
        print(f"marionette scene build: {e}", file=sys.stderr)
        return 1
    out = args.scene.with_suffix(".xml")
    out.write_text(text)
    try:
        from marionette._core import sim

        sim.MjScene(str(out))
    except ImportError:
        pass
    except Exception as e:
        print(f"marionette scene build: MuJoCo refuses {out}: {e}", file=sys.stderr)
        return 1
    print(f"wrote {out}")
    return 0
