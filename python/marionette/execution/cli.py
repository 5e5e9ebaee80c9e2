"""``marionette supervise PLAN`` runs a plan on a running marionette-controller (factory +
supervisor FSM); ``marionette fsm state|events|inject EVENT`` inspects and drives the FSM."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "supervise",
        help="execute a plan on a running controller (one controller per transition)",
        description="Generate the controllers of PLAN (written to --specs), estimate where the "
        "plan stands from the robot's state, and run the supervisor FSM against the "
        "marionette-controller listening on the LCM URL.",
        epilog=(
            "example:\n"
            "  marionette plan ur10_box --out /tmp/p\n"
            "  marionette-controller --robot ur10 --scene models/scenes/ur10_box.xml &\n"
            "  marionette supervise /tmp/p/plan.json"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("plan", type=Path, help="plan.json written by `marionette plan`")
    p.add_argument("--lcm-url", default=None)
    p.add_argument("--specs", type=Path, default=None, help="where to write the controllers (YAML)")
    p.add_argument(
        "--step",
        action="store_true",
        help="wait for `marionette fsm inject approve` before each step",
    )
    p.add_argument("--max-joint-velocity", type=float, default=0.5, help="[rad/s] (default 0.5)")
    p.add_argument(
        "--no-sim-grasp",
        action="store_true",
        help="do not weld grasps in the simulator (kinematic backend, real robot)",
    )
    p.add_argument(
        "--gripper-admittance",
        action="store_true",
        help="gripper_admittance tasks while a gripper with a joint holds (thesis 000 §3.2.4.3)",
    )
    p.add_argument(
        "--monitor",
        action="store_true",
        help="execution monitor: left_manifold when OBJECT_POSES leave the step's constraints",
    )
    p.add_argument(
        "--from-step",
        type=int,
        default=None,
        help="start at this step (default: from the estimated state)",
    )
    p.set_defaults(func=run_supervise)

    f = subparsers.add_parser(
        "fsm",
        help="supervisor FSM: state, events, inject an event",
        epilog=(
            "examples:\n"
            "  marionette fsm state\n"
            "  marionette fsm events --count 10\n"
            "  marionette fsm inject approve"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("--lcm-url", default=None)
    f.add_argument("--timeout", type=float, default=5.0, help="[s] to wait for messages")
    sub = f.add_subparsers(dest="fsm_command", required=True, metavar="ACTION")
    sub.add_parser("state", help="print the supervisor's state")
    ev = sub.add_parser("events", help="print events as they come (until --timeout)")
    ev.add_argument("--count", type=int, default=0, help="stop after this many (0: until timeout)")
    inj = sub.add_parser("inject", help="send an event to the supervisor")
    from marionette.execution.supervisor import INJECTABLE

    inj.add_argument("event", choices=INJECTABLE, help="the event to send")
    inj.add_argument("--detail", default="")
    inj.add_argument("--value", type=float, default=0.0)
    f.set_defaults(func=run_fsm)


def run_supervise(args: argparse.Namespace) -> int:
    import numpy as np

    from marionette import robots
    from marionette.control.client import ControllerClient, configuration_from_state
    from marionette.execution.estimation import (
        estimate_state,
        first_step_to_run,
        measured_configuration,
    )
    from marionette.execution.factory import (
        build_specs,
        check_specs,
        context_from_plan,
        write_specs,
    )
    from marionette.execution.plan_steps import PlanError, PlanRobotMap, plan_robot, steps_from_plan
    from marionette.execution.supervisor import Supervisor, SupervisorOptions
    from marionette.planning.path import load_plan

    try:
        plan = load_plan(args.plan)
        robot = plan_robot(plan)
        model, _ = robots.load_pinocchio(robot, with_collision=False)
        robot_map = PlanRobotMap(plan.doc["problem"]["configuration_layout"], model, robot)
        steps = steps_from_plan(plan)
    except (OSError, ValueError, PlanError) as e:
        print(f"marionette supervise: {args.plan}: {e}", file=sys.stderr)
        return 1
    ctx = context_from_plan(plan.doc, robot, model, gripper_admittance=args.gripper_admittance)
    specs = build_specs(steps, ctx)
    specs_path = args.specs or args.plan.with_name("controllers.yaml")
    write_specs(specs_path, steps, specs, plan.doc["problem"]["name"])
    problems = check_specs(steps, specs, ctx, robot_map)
    print(f"{len(steps)} steps -> {specs_path}")
    if problems:
        print(
            "marionette supervise: the controllers fail their checks:\n  " + "\n  ".join(problems),
            file=sys.stderr,
        )
        return 1
    with ControllerClient(args.lcm_url) as client:
        try:
            client.wait_ready(10.0)
        except TimeoutError as e:
            print(f"marionette supervise: no controller: {e}", file=sys.stderr)
            return 1
        first = args.from_step
        if first is None:
            from marionette.planning.graph_factory import graph_from_settings
            from marionette.planning.problem import load_problem

            graph = graph_from_settings(load_problem(plan.doc["problem"]["source"]))
            q0 = np.array(plan.doc["problem"]["q_init"])
            objects = {}
            if client.objects is not None:
                objects = {
                    n: client.object_pose(n)
                    for n in robot_map.objects
                    if any(o.object_name == n for o in client.objects.objects)
                }
            measured = measured_configuration(
                q0, robot_map, configuration_from_state(model, client.state), objects
            )
            estimate = estimate_state(graph, measured)
            first = first_step_to_run(steps, robot_map, estimate)
            print(
                f"estimated state {estimate.state!r} (residual {estimate.residual:.2e}): "
                f"starting at step {first}"
            )
        options = SupervisorOptions(
            max_joint_velocity=args.max_joint_velocity,
            simulated_grasps=not args.no_sim_grasp,
            step_mode=args.step,
        )
        supervisor = Supervisor(
            client, steps, specs, robot_map, options, plan.doc["problem"]["name"]
        )
        if args.monitor:
            from marionette.execution.monitor import ExecutionMonitor, MonitorNode

            MonitorNode(client.bus, ExecutionMonitor(model, ctx), steps)
        result = supervisor.run(first)
    for r in result.records:
        print(f"  step {r.index:2d} {r.transition:45s} {r.result}")
    print(f"supervisor: {result.state}" + (f" ({result.reason})" if result.reason else ""))
    return 0 if result.success else 1


def _more_than(n: int) -> Callable[[list[Any]], bool]:
    """A wait condition: more than ``n`` messages received."""
    return lambda messages: len(messages) > n


def run_fsm(args: argparse.Namespace) -> int:
    from marionette import channels, lcmt_supervisor_event, lcmt_supervisor_state
    from marionette.execution.decisions import event_message
    from marionette.lcm_bus import LcmBus, MessageLog

    with LcmBus(args.lcm_url) as bus:
        if args.fsm_command == "inject":
            bus.publish(
                channels.SUPERVISOR_EVENT,
                event_message(int(time.time() * 1e6), args.event, "cli", args.detail, args.value),
            )
            print(f"sent {args.event}")
            return 0
        if args.fsm_command == "state":
            states = MessageLog(bus, channels.SUPERVISOR_STATE, lcmt_supervisor_state)
            bus.start()
            if not states.wait_for(lambda m: len(m) > 0, args.timeout):
                print(
                    f"marionette fsm state: no SUPERVISOR_STATE within {args.timeout} s "
                    f"(is a supervisor running on {bus.url}? `marionette demo` or "
                    "`marionette supervise` runs one)",
                    file=sys.stderr,
                )
                return 1
            s = states.latest()
            assert s is not None  # wait_for saw one, and the log only grows
            print(
                f"{s.plan_name}: step {s.step_index + 1}/{s.num_steps} {s.state!r} "
                f"[{s.status}] {s.detail}"
            )
            return 0
        events = MessageLog(bus, channels.SUPERVISOR_EVENT, lcmt_supervisor_event)
        bus.start()
        shown = 0
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline and (args.count == 0 or shown < args.count):
            events.wait_for(_more_than(shown), max(0.0, deadline - time.monotonic()))
            for e in events.messages[shown:]:
                print(f"{e.utime * 1e-6:10.3f}  {e.source:10s} {e.name:20s} {e.detail}")
                shown += 1
        if shown == 0 or shown < args.count:
            print(
                f"marionette fsm events: {shown} of {args.count or 'any'} SUPERVISOR_EVENT within "
                f"{args.timeout} s (is a supervisor running on {bus.url}? a longer --timeout "
                "waits more)",
                file=sys.stderr,
            )
            return 1
        return 0
