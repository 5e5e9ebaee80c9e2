"""``marionette view --robot R [--scene S]``: the browser 3D view of the run on the LCM URL."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view",
        help="serve a browser 3D view (meshcat) of the run on the LCM URL",
        description="Draws ROBOT_STATE, SIM_OBJECT_POSES/OBJECT_POSES, FOOTSTEP_PLAN and "
        "SUPERVISOR_STATE in a meshcat page; prints its URL. Stops on Ctrl-C.",
        epilog=("example:\n  marionette view --robot ur10 --scene models/scenes/ur10_box.xml"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--robot", required=True, help="robot name or folder (docs/robots.md)")
    p.add_argument(
        "--scene",
        type=Path,
        default=None,
        help="the run's MJCF scene (its .yaml names the objects' models)",
    )
    p.add_argument("--lcm-url", default=None, help="default: $MARIONETTE_LCM_URL or LCM's default")
    p.add_argument(
        "--url-file", type=Path, default=None, help="write the page's URL there once ready"
    )
    p.add_argument("--rate", type=float, default=20.0, help="robot redraws per second (default 20)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from marionette.viewer.node import serve
    from marionette.viewer.scene import ViewerError

    if args.rate <= 0:
        print("marionette view: --rate must be > 0", file=sys.stderr)
        return 2
    if args.scene is not None and not args.scene.is_file():
        print(f"marionette view: no scene file {args.scene} (models/scenes/*.xml)", file=sys.stderr)
        return 1
    try:
        return serve(args.robot, args.scene, args.lcm_url, args.url_file, args.rate)
    except ViewerError as e:
        print(f"marionette view: {e}", file=sys.stderr)
        return 1
