"""``marionette footsteps run|plan``: the footstep process, and one-shot plans with a figure."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from marionette.footsteps.augmented_robot import Stance


def _stance(values) -> Stance | None:
    from marionette.footsteps.augmented_robot import Stance

    if values is None:
        return None
    lx, ly, lyaw, rx, ry, ryaw = values
    return Stance(np.array([lx, ly, lyaw]), np.array([rx, ry, ryaw]))


def _options(args):
    from marionette.footsteps.node import NodeOptions

    return NodeOptions(
        robot=args.robot,
        mode=args.mode,
        target=args.target,
        target_point=tuple(args.target_point),
        hand=args.hand,
        posture_frozen=not args.full_replan,
        bar=args.bar,
        bar_axis_yaw=args.bar_axis_yaw,
        bar_radius=args.bar_radius,
        bar_length=args.bar_length,
        goal=tuple(args.goal),
        swing_margin=args.swing_margin,
        crossing_duration=args.crossing_duration,
    )


def _run(args: argparse.Namespace) -> int:
    from marionette.footsteps.node import run

    return run(_options(args), args.lcm_url, args.rate, _stance(args.stance), args.duration)


def _plan(args: argparse.Namespace) -> int:
    from marionette.footsteps.augmented_robot import Stance
    from marionette.footsteps.obstacles import Bar, Obstacle
    from marionette.footsteps.plot import plot_plan

    stance = _stance(args.stance) or Stance(
        np.array([0.0, 0.085, 0.0]), np.array([0.0, -0.085, 0.0])
    )
    from marionette.footsteps.node import resolve_walking_robot
    from marionette.footsteps.robot_model import walking_robot

    robot = walking_robot(resolve_walking_robot(args.robot))
    obstacles: list[Obstacle] = []
    goal: np.ndarray | None = None  # step-over: the final stance
    hand: np.ndarray | None = None  # grasp: the object
    if args.mode == "grasp":
        from marionette.footsteps.planner import GraspPlanner, GraspPlannerOptions

        hand = np.array(args.object)
        grasp = GraspPlanner(robot, stance, hand, options=GraspPlannerOptions(hand=args.hand))
        report = grasp.plan()
        plan, foot = grasp.result(), grasp.augmented.foot
    else:
        from marionette.footsteps.step_over import StepOverOptions, StepOverPlanner

        bar = Bar(np.array(args.bar_pose[:2]), args.bar_pose[2], args.bar_radius, args.bar_length)
        goal = np.array(args.goal)
        step_over = StepOverPlanner(
            stance,
            goal,
            bar,
            robot.foot,
            options=StepOverOptions(swing_margin=args.swing_margin).with_crossing_duration(
                args.crossing_duration
            ),
        )
        report = step_over.plan()
        plan, foot = step_over.result(), step_over.foot
        obstacles.append(bar)
    print(
        f"converged={report.converged} iterations={report.iterations} "
        f"steps={len(plan.steps)} time={1e3 * report.time_s:.1f} ms"
    )
    for step in plan.steps:
        x, y, _z, yaw = step.pose
        print(
            f"  {step.index:2d} {'L' if step.is_left else 'R'} x={x:+.3f} y={y:+.3f} "
            f"yaw={yaw:+.3f}" + (f" via={step.via.round(3).tolist()}" if step.via.size else "")
        )
    if args.png:
        plot_plan(
            args.png,
            plan,
            foot,
            obstacles,
            goal=goal,
            hand_target=hand,
            title=f"marionette footsteps ({args.mode})",
        )
        print(f"wrote {args.png}")
    return 0 if report.converged else 1


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--robot",
        default="",
        help="robot with two feet (name or folder; default: the only one found)",
    )
    p.add_argument("--mode", choices=["grasp", "step-over"], default="grasp")
    p.add_argument("--hand", choices=["left", "right"], default="right")
    p.add_argument(
        "--stance",
        type=float,
        nargs=6,
        metavar=("LX", "LY", "LYAW", "RX", "RY", "RYAW"),
        help="initial soles (default: from WALK_STATUS when standing)",
    )
    p.add_argument("--bar-radius", type=float, default=0.02)
    p.add_argument("--bar-length", type=float, default=2.0)
    p.add_argument(
        "--goal",
        type=float,
        nargs=3,
        default=[2.0, 0.0, 0.0],
        metavar=("X", "Y", "YAW"),
        help="final stance (step-over)",
    )
    p.add_argument(
        "--swing-margin",
        type=float,
        default=0.03,
        help="clearance [m] of the crossing swings above the bar (step-over, eq. 5.1)",
    )
    p.add_argument(
        "--crossing-duration",
        type=float,
        default=None,
        help="single support [s] of the two swings over the bar (step-over; they rise, cross "
        "level and land; default: the planner's)",
    )


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "footsteps",
        help="footstep optimiser (Dang 2012)",
        epilog=(
            "examples:\n"
            "  marionette footsteps plan --mode grasp --png steps.png\n"
            "  marionette footsteps run --mode step-over --goal 1.8 0 0"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="footsteps_command", required=True)

    run = sub.add_parser("run", help="the LCM process: OBJECT_POSES, WALK_STATUS -> FOOTSTEP_PLAN")
    _common(run)
    run.add_argument("--lcm-url", default=None)
    run.add_argument("--target", default="ball", help="object to grasp (grasp mode)")
    run.add_argument(
        "--target-point",
        type=float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("X", "Y", "Z"),
        help="the point the hand reaches, in the target object's frame [m] (default its origin; "
        "e.g. a ball resting on the tracked pedestal: 0 0 <height>)",
    )
    run.add_argument("--bar", default="bar", help="object name of the bar (step-over mode)")
    run.add_argument(
        "--bar-axis-yaw",
        type=float,
        default=0.0,
        help="direction of the bar's axis in its object frame, as a yaw about z [rad] (default "
        "0: along x; the tagged bar of models/objects lies along y: pi/2)",
    )
    run.add_argument(
        "--full-replan",
        action="store_true",
        help="replan the posture too (default: posture frozen, Dang §6.2.2)",
    )
    run.add_argument("--rate", type=float, default=50.0, help="replanning checks per second")
    run.add_argument("--duration", type=float, default=None, help="stop after this [s]")
    run.set_defaults(func=_run)

    plan = sub.add_parser("plan", help="one plan from the command line, optionally a PNG")
    _common(plan)
    plan.add_argument(
        "--object",
        type=float,
        nargs=3,
        default=[2.0, -0.2, 0.6],
        metavar=("X", "Y", "Z"),
        help="object to grasp (grasp mode)",
    )
    plan.add_argument(
        "--bar-pose",
        type=float,
        nargs=3,
        default=[1.0, 0.0, np.pi / 2],
        metavar=("X", "Y", "YAW"),
        help="bar centre and axis yaw (step-over)",
    )
    plan.add_argument("--png", default=None, help="write a top view here")
    plan.set_defaults(func=_plan)
