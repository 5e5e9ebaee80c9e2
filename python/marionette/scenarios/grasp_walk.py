"""``grasp-walk`` (Dang 2012 ch. 6): TALOS walks to a ball that is moved while it walks.

The footstep process (`marionette footsteps run`, posture frozen when replanning) plans the steps to
a stance from which the right hand reaches the ball and publishes
FOOTSTEP_PLAN; marionette-controller's walking stack (:func:`walking.walking_spec`) executes
them; the ball is moved sideways during the walk, the footstep process replans and the
controller's footstep manager applies the new steps to the steps not yet started.

Scene: TALOS alone on the floor (``models/talos/talos.xml``). In ``talos_walk`` the bar (1 m
ahead) lies across the path and the ball sits on a pedestal 2.2 m ahead behind it; the pedestal
is a fixture (SIM_COMMAND ``slide`` could carry it) and a ball moved off its pedestal falls.
The ball here is the target the demo publishes on OBJECT_POSES (the perception output the
footstep process listens to; Dang's ball was tracked by motion capture) and moves during the
walk. Success (``docs/scenarios.md``, without the final grasp): the robot stops on the final
stance of the last plan with the ball within reach of its right arm, never falls, and its
measured ZMP stays inside the support polygon of its loaded soles.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pinocchio as pin

from marionette import lcmt_object_poses, robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.references import minimum_jerk
from marionette.execution.walking import (
    FEET,
    MergedPlan,
    sole_half_size,
    walking_spec,
    zmp_margins,
)
from marionette.scenarios.base import Criterion, RunOptions, Scenario
from marionette.scenarios.report import (
    controller_and_plots_lines,
    save_figure,
    speed_text,
    timings_lines,
    title,
    write_report_files,
)
from marionette.scenarios.walking_scenario import (
    MIN_REPLAN_HZ,
    MovingObjectPublisher,
    WalkRecorder,
    draw_floor_move,
    finish_footsteps_axes,
    object_poses_message,
    plot_footsteps,
    replan_criteria,
    replan_rate_row,
    sole_poses,
    step_counts,
    walk_while_object_moves,
    walking_run,
)

ROBOT = "talos"


@dataclass(frozen=True)
class GraspWalkSettings:
    """Where the ball starts and how it is moved (relative to the initial stance centre)."""

    ball: tuple[float, float, float] = (1.3, -0.10, 0.842)  # [m] ahead, left, height (pedestal top)
    shift: tuple[float, float] = (0.0, -0.15)  # [m] ball displacement during the walk
    shift_at_step: int = 1  # the move starts when this step starts
    shift_duration_s: float = 1.5  # [s] of controller time: pushed, not teleported
    hand: str = "right"
    stance_tolerance: float = 0.02  # [m] executed final soles vs the last plan's
    stance_yaw_tolerance_deg: float = 3.0
    max_base_drop: float = 0.05  # [m] fall criterion (base height)
    zmp_tolerance: float = 0.005  # [m] ZMP outside the soles' polygon allowed by
    # the sole poses (walk references, mm from the real ones)
    walk_timeout_s: float = 60.0  # controller time for the whole walk
    reach: bool = True  # then reach the ball with the hand (bonus)
    reach_duration_s: float = 3.0  # [s] minimum-jerk hand motion
    reach_tolerance: float = 0.03  # [m] grasp point to ball after the reach

    @classmethod
    def drawn(cls, seed: int, max_distance: float = 0.3) -> GraspWalkSettings:
        """A trial's settings (``--seed``): the ball moved during the walk by a seeded floor move
        of 0.1-0.3 m in any direction (:func:`draw_floor_move`)."""
        dx, dy = draw_floor_move(seed, max_distance)
        return cls(shift=(float(dx), float(dy)))


def ball_message(utime: int, p_W: np.ndarray) -> lcmt_object_poses:
    """OBJECT_POSES with the ball (name "ball") at ``p_W``, as motion capture gives it (Dang's
    ball was tracked by motion capture)."""
    return object_poses_message(utime, "ball", p_W, (1.0, 0.0, 0.0, 0.0), "motion_capture")


def arm_reach(model: pin.Model, hand: str) -> tuple[float, str]:
    """Reach [m] of the ``hand`` arm: shoulder (``arm_<hand>_1`` joint) to grasp point with the
    arm stretched (arm joints at zero: TALOS' arm hangs straight), and the shoulder frame."""
    q = pin.neutral(model)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    shoulder = f"arm_{hand}_1_link"
    grasp = f"{hand}_grasp_point"
    d = np.linalg.norm(
        data.oMf[model.getFrameId(grasp)].translation
        - data.oMf[model.getFrameId(shoulder)].translation
    )
    return float(d), shoulder


@dataclass(frozen=True, kw_only=True)
class GraspWalk(Scenario):
    """The grasp-walk kind: ``settings`` None draws each trial's from its seed
    (:meth:`GraspWalkSettings.drawn`)."""

    KIND: ClassVar[str] = "grasp-walk"
    DRAW_KEYS: ClassVar[tuple[str, ...]] = ("settings.shift",)

    settings: GraspWalkSettings | None = None

    def criteria(self) -> tuple[Criterion, ...]:
        s = self.settings or GraspWalkSettings()
        return (
            Criterion(
                "final_stance_ok",
                "executed final soles vs the last footstep plan",
                f"{s.stance_tolerance * 1e3:g} mm, {s.stance_yaw_tolerance_deg:g}°",
            ),
            Criterion("ball_within_reach", f"ball to the {s.hand} shoulder", "the arm's reach"),
            Criterion("no_fall", "base height drop (max)", f"< {s.max_base_drop * 1e3:g} mm"),
            Criterion(
                "zmp_inside",
                "measured ZMP in the loaded soles' polygon (over 80 % of the walk's statuses)",
                f"> -{s.zmp_tolerance * 1e3:g} mm",
            ),
            Criterion("steps_in_order", "steps executed in order", "never back"),
            Criterion("recomputations_after_move", "footstep replans after the ball moved", "> 0"),
            Criterion(
                "replan_fast_enough", "1 / median footstep replan time", f">= {MIN_REPLAN_HZ:g} Hz"
            ),
        )

    def declared_settings(self) -> dict[str, Any]:
        if self.settings is not None:
            return dataclasses.asdict(self.settings)
        return {**dataclasses.asdict(GraspWalkSettings()), "shift": "drawn from the seed"}

    def trial(
        self, seed: int, out_dir: Path, options: RunOptions, report: dict[str, Any]
    ) -> dict[str, Any]:
        return run_grasp_walk(self, seed, out_dir, options, report)


def run_grasp_walk(
    scenario: GraspWalk,
    seed: int,
    out_dir: Path,
    options: RunOptions,
    report: dict[str, Any],
) -> dict[str, Any]:
    """Runs one grasp-walk trial and writes its report folder; returns the report dictionary."""
    from marionette.footsteps.robot_model import walking_robot

    log = options.log
    settings = scenario.settings or GraspWalkSettings.drawn(seed)
    model = walking_robot(scenario.robot).model  # with the grasp-point frames of the planner
    report["settings"] = settings.__dict__
    with walking_run(scenario.robot, model, scenario.scene, out_dir, options, report) as run:
        client, rec, mid = run.client, run.rec, run.mid
        ball0 = np.array([mid[0] + settings.ball[0], mid[1] + settings.ball[1], settings.ball[2]])
        ball1 = ball0 + np.array([*settings.shift, 0.0])
        publisher = MovingObjectPublisher(client, "ball", ball0, ball_message)
        utime_move = walk_while_object_moves(
            run,
            publisher,
            ["--target", "ball", "--hand", settings.hand],
            ball1,
            settings.shift_at_step,
            settings.shift_duration_s,
            settings.walk_timeout_s,
            f"grasp-walk: ball at {np.round(ball0, 3).tolist()}, footstep process started",
            "grasp-walk",
            log,
        )
        report["reach_start_utime"] = client.utime()
        if settings.reach:
            t2 = time.perf_counter()
            report["reach"] = _reach(client, model, ball1, settings, scenario.robot, log)
            run.timings["reach_wall_s"] = time.perf_counter() - t2
    report.update(
        _criteria(
            settings,
            model,
            rec,
            run.start,
            run.q_start,
            run.q_final,
            ball0,
            ball1,
            run.utime_start,
            utime_move,
            run.footsteps_log,
        )
    )
    report["summary"] = summary(report)
    write_grasp_walk_report(out_dir, report, rec, ball0, ball1, utime_move, model)
    return report


def reach_spec(controller_id: int, robot: str, hand: str) -> ControllerSpec:
    """Standing reach of ``robot``: feet, CoM and the waist (roll, pitch, yaw) held where they
    are at level 0, the gripper following a streamed position at level 1, posture at level 2.

    Every reference holds the value of the swap's tick, so the stack's first command is ~0 and
    the swap passes the default jump bound: at rest the walking stack's joint command is ~0 too
    (its base "command", toward soles that landed a few mm from their references, drives no joint
    and is not part of the check). Holding the walk's references instead would keep that base
    motion and let the hand task, holding its world position, turn it into arm motion (0.07-0.29
    rad/s measured after 6-8 steps)."""
    walk = {t.name: t for t in walking_spec(robot, controller_id).tasks}
    held = [
        dataclasses.replace(walk[name], reference_channel="", reference=())
        for name in ("left_foot", "right_foot", "com", "waist")
    ]
    return ControllerSpec(
        controller_id,
        "reach",
        tasks=[
            *held,
            TaskSpec(
                "hand", "position", 1, frame=f"gripper_{hand}_base_link", gain=5.0, streamed=True
            ),
            dataclasses.replace(walk["posture"], priority=2),
        ],
    )


def _swap_decided(cid: int) -> Callable[[ControllerClient], bool]:
    """A wait condition: the controller took the swap to controller ``cid``, or refused it."""
    tag = f"(id {cid})"
    return lambda c: (
        c.status.active_controller_id == cid
        or tag in c.status.last_switch_result
        or tag in c.status.last_rejection
    )


def _later_than(utime: int) -> Callable[[ControllerClient], bool]:
    """A wait condition: the controller's clock past ``utime``."""
    return lambda c: c.utime() > utime


def _reach(
    client: ControllerClient,
    model: pin.Model,
    ball: np.ndarray,
    settings: GraspWalkSettings,
    robot: str,
    log: Callable[[str], None],
) -> dict[str, Any]:
    """Bonus: swap to :func:`reach_spec` and bring the grasp point onto the ball. The gripper base
    aims 0.12 m short of the ball along the shoulder-ball line (the grasp point is that far
    along the forearm's axis, the gripper frame's origin in robot.yaml); the result is measured
    at the grasp point."""
    from marionette.execution.streamer import ReferenceStreamer

    hand = settings.hand
    grasp_point = np.array(robots.semantics(robot).gripper(f"{robot}/{hand}_gripper").pose.xyz)
    data = model.createData()
    pin.framesForwardKinematics(model, data, configuration_from_state(model, client.state))
    p_hand = data.oMf[model.getFrameId(f"gripper_{hand}_base_link")].translation.copy()
    shoulder = data.oMf[model.getFrameId(f"arm_{hand}_1_link")].translation.copy()
    u = (ball - shoulder) / np.linalg.norm(ball - shoulder)
    target = ball - np.linalg.norm(grasp_point) * u
    cid = 2
    client.send_spec(reach_spec(cid, robot, hand))
    try:
        client.wait(_swap_decided(cid), 10.0, "the swap to the reach controller")
    except TimeoutError as e:
        return {"done": False, "reason": str(e)}
    if client.status.active_controller_id != cid:
        tag = f"(id {cid})"
        st = client.status
        return {
            "done": False,
            "reason": st.last_switch_result if tag in st.last_switch_result else st.last_rejection,
        }
    # The grasp point's offset from the gripper base depends on the hand's orientation, which the
    # position task leaves to the posture: correct the base's target by the measured offset and
    # move again (two short corrections, each from the previous target: no reference jump).
    chunks, lookahead, errors = 0, [], []
    for duration in (settings.reach_duration_s, 1.0, 1.0):
        values, derivatives = minimum_jerk(p_hand, target, duration, 1e-3)
        streamer = ReferenceStreamer(
            client.send_reference,
            cid,
            {"hand": (values, derivatives)},
            client.utime() + 100_000,
            1000,
            200,
            1.0,
        )
        while not (streamer.done and client.utime() >= streamer.end_utime):
            now = client.utime()
            streamer.pump(now)
            client.wait(_later_than(now), 5.0, "controller time to advance")
        client.wait_time(0.5)
        chunks += streamer.chunks_sent
        if streamer.min_margin_us is not None:
            lookahead.append(streamer.min_margin_us / 1e3)
        pin.framesForwardKinematics(model, data, configuration_from_state(model, client.state))
        X_hand = data.oMf[model.getFrameId(f"gripper_{hand}_base_link")]
        grasp = X_hand.act(grasp_point)
        errors.append(float(np.linalg.norm(grasp - ball)))
        p_hand, target = target, ball - (grasp - X_hand.translation)
    error = errors[-1]
    log(f"grasp-walk: reach done, grasp point {error * 1e3:.1f} mm from the ball")
    return {
        "done": True,
        "grasp_point_to_ball_m": error,
        "ok": bool(error <= settings.reach_tolerance),
        "errors_per_pass_m": errors,
        "hand_task_error_m": float(client.task_error("hand")),
        "chunks": chunks,
        "min_lookahead_ms": min(lookahead) if lookahead else None,
    }


def _criteria(
    settings: GraspWalkSettings,
    model: pin.Model,
    rec: WalkRecorder,
    start,
    q_start,
    q_final,
    ball0,
    ball1,
    utime_start: int,
    utime_move: int,
    footsteps_log: list[str],
) -> dict[str, Any]:
    """The success criteria, measured (module docstring)."""
    planned = rec.merged.final_stance(start)
    executed = sole_poses(model, q_final)
    stance_err = max(float(np.linalg.norm(executed[s][:2] - planned[s][:2])) for s in FEET)
    yaw_err = max(
        abs(float(np.degrees(np.angle(np.exp(1j * (executed[s][3] - planned[s][3]))))))
        for s in FEET
    )
    # The ball within reach of the right arm from where the robot stopped.
    reach, shoulder = arm_reach(model, settings.hand)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q_final)
    ball_dist = float(np.linalg.norm(ball1 - data.oMf[model.getFrameId(shoulder)].translation))
    # The replans followed the ball: the final stance moved with it (the first plan's final
    # stance is where the robot would have stopped for the ball where it was).
    first = MergedPlan()
    first.apply(rec.plans[0][1], -1)
    first_stance = first.final_stance(start)
    stance_shift = 0.5 * sum(planned[s][:2] - first_stance[s][:2] for s in FEET)
    base_drop = float(max(q_start[2] - q[2] for q in rec.q))
    walked = [s for s in rec.statuses if s.utime >= utime_start]
    margins = zmp_margins(walked, rec.loaded, sole_half_size(robots.robot(ROBOT).mjcf))
    replans = [p for u, p in rec.plans[1:]]
    after_move = [p for u, p in rec.plans if u >= utime_move]
    c: dict[str, Any] = {
        **step_counts(rec, walked),
        "footstep_recomputations": len(replans),
        "recomputations_after_move": len(after_move),
        **replan_criteria(rec, footsteps_log, utime_move, settings.shift_duration_s),
        "final_stance_error_m": stance_err,
        "final_stance_yaw_error_deg": yaw_err,
        "final_stance_ok": bool(
            stance_err <= settings.stance_tolerance and yaw_err <= settings.stance_yaw_tolerance_deg
        ),
        "ball_to_shoulder_m": ball_dist,
        "arm_reach_m": reach,
        "ball_within_reach": bool(ball_dist <= reach),
        "final_stance_shift_m": stance_shift.tolist(),
        "ball_shift_m": list(settings.shift),
        "base_max_drop_m": base_drop,
        "no_fall": bool(base_drop < settings.max_base_drop),
        "zmp_samples": len(margins),
        "zmp_statuses": len(walked),
        "zmp_margin_min_m": float(margins[:, 1].min()) if len(margins) else None,
        "zmp_margin_p5_m": float(np.percentile(margins[:, 1], 5)) if len(margins) else None,
        "zmp_margin_median_m": float(np.median(margins[:, 1])) if len(margins) else None,
        "zmp_inside": bool(
            len(margins) > 0.8 * len(walked) and margins[:, 1].min() > -settings.zmp_tolerance
        ),
        "final_stance": {s: planned[s].tolist() for s in FEET},
        "executed_final_soles": {s: executed[s].tolist() for s in FEET},
    }
    ok = (
        c["final_stance_ok"]
        and c["ball_within_reach"]
        and c["no_fall"]
        and c["zmp_inside"]
        and c["steps_in_order"]
        and c["recomputations_after_move"] > 0
        and c["replan_fast_enough"]
    )
    return {"success": bool(ok), "criteria": c}


def write_grasp_walk_report(
    out_dir: Path,
    report: dict[str, Any],
    rec: WalkRecorder,
    ball0,
    ball1,
    utime_move: int,
    model: pin.Model,
) -> None:
    """report.json, report.md and the plots (footsteps planned vs executed, CoM/ZMP)."""
    write_report_files(
        out_dir, report, lambda: _plots(out_dir, rec, ball0, ball1, utime_move, model), _markdown
    )


def summary(report: dict[str, Any]) -> str:
    """One line for the terminal."""
    c = report["criteria"]
    return (
        f"{'SUCCESS' if report['success'] else 'FAILURE'}: {c['steps_executed']} steps, "
        f"{c['footstep_recomputations']} footstep recomputations "
        f"({c['recomputations_after_move']} after the ball moved), final stance "
        f"{c['final_stance_error_m'] * 1e3:.1f} mm from the plan, ball "
        f"{c['ball_to_shoulder_m']:.2f} m "
        f"from the shoulder (reach {c['arm_reach_m']:.2f} m), base drop "
        f"{c['base_max_drop_m'] * 1e3:.0f} mm, ZMP margin min "
        f"{_mm(c['zmp_margin_min_m'])} / median {_mm(c['zmp_margin_median_m'])}"
    )


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1e3:.1f} mm"


def _markdown(r: dict[str, Any]) -> str:
    c = r["criteria"]
    s = r["settings"]
    ms = c["replan_solve_ms"]
    lines = [
        title(r),
        "",
        r.get("description", ""),
        "",
        f"robot talos, scene `{r['scene']}` (TALOS alone: the ball is the target published on "
        f"OBJECT_POSES), {speed_text(r['speed'])}",
        "",
        summary(r),
        "",
        "## Success criteria",
        "",
        "| criterion | measured | limit | ok |",
        "|---|---|---|---|",
        f"| executed final soles vs last plan | {c['final_stance_error_m'] * 1e3:.1f} mm, "
        f"{c['final_stance_yaw_error_deg']:.2f}° | {s['stance_tolerance'] * 1e3:.0f} mm, "
        f"{s['stance_yaw_tolerance_deg']}° | {c['final_stance_ok']} |",
        f"| ball to right shoulder | {c['ball_to_shoulder_m']:.3f} m | arm reach "
        f"{c['arm_reach_m']:.3f} m | {c['ball_within_reach']} |",
        f"| base height drop (max) | {c['base_max_drop_m'] * 1e3:.1f} mm | "
        f"{s['max_base_drop'] * 1e3:.0f} mm | {c['no_fall']} |",
        f"| measured ZMP in the loaded soles' polygon (min margin; p5, median) | "
        f"{_mm(c['zmp_margin_min_m'])}; {_mm(c['zmp_margin_p5_m'])}, "
        f"{_mm(c['zmp_margin_median_m'])} "
        f"over {c['zmp_samples']}/{c['zmp_statuses']} statuses | > "
        f"-{s['zmp_tolerance'] * 1e3:.0f} mm "
        f"| {c['zmp_inside']} |",
        f"| steps in order | {c['steps_executed']} executed | - | {c['steps_in_order']} |",
        f"| replans after the ball moved | {c['recomputations_after_move']} | > 0 | "
        f"{c['recomputations_after_move'] > 0} |",
        replan_rate_row(c, "ball"),
        "",
        "## Bonus: reaching the ball",
        "",
        _reach_line(r.get("reach"), s),
        "",
        "## Footstep recomputations (Dang 2012 §6.3: 97 in 14 s)",
        "",
        f"{c['footstep_plans']} plans: the first ({c['steps_planned_first']} steps, "
        f"{_num(ms['first_plan'])} ms) and {c['footstep_recomputations']} recomputations "
        f"(median {_num(ms['median'])} ms, max {_num(ms['max'])} ms, posture frozen). The "
        f"footstep process replans when the ball moves by more than 2 mm or a step starts. "
        f"Final stance moved by {np.round(c['final_stance_shift_m'], 3).tolist()} m for a "
        f"ball moved by {c['ball_shift_m']} m.",
        "",
        *timings_lines(r["timings"]),
        *controller_and_plots_lines(r),
        "",
        "Files: `run.lcmlog` (every LCM message of the run), `logs/` (process outputs: "
        "controller, footsteps, lcm-logger).",
    ]
    return "\n".join(lines) + "\n"


def _reach_line(reach: dict[str, Any] | None, s: dict[str, Any]) -> str:
    if reach is None:
        return "not attempted"
    if not reach["done"]:
        return f"not done: {reach['reason']}"
    passes = ", ".join(f"{1e3 * e:.1f}" for e in reach["errors_per_pass_m"])
    return (
        f"after the walk, a reach controller (feet and CoM held, hand streamed at level 1) "
        f"brings the grasp point {reach['grasp_point_to_ball_m'] * 1e3:.1f} mm from the ball "
        f"(limit {s['reach_tolerance'] * 1e3:.0f} mm, {'ok' if reach['ok'] else 'missed'}; per "
        f"pass {passes} mm; hand task error {reach['hand_task_error_m'] * 1e3:.1f} mm). Not part "
        f"of the success verdict; no ball in the scene to close the gripper on."
    )


def _num(v) -> str:
    return "-" if v is None else f"{v:.0f}"


def _plots(
    out_dir: Path, rec: WalkRecorder, ball0, ball1, utime_move: int, model: pin.Model
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from marionette.footsteps.robot_model import FootShape

    half = sole_half_size(robots.robot(ROBOT).mjcf)
    foot = FootShape(length=2 * half[0], width=2 * half[1])
    paths = []
    data = model.createData()
    com = np.array([pin.centerOfMass(model, data, q) for q in rec.q])
    t_q = np.array(rec.utimes) * 1e-6

    # 1. Top view: first plan (faded), the steps executed (merged plans), measured soles at
    # each landing, CoM path, the ball before and after its move.
    fig, ax = plt.subplots(figsize=(8, 6))
    plot_footsteps(ax, rec, model, foot)
    ax.plot(com[:, 0], com[:, 1], color="tab:green", lw=1, label="CoM (measured)")
    ax.plot(*ball0[:2], "o", color="0.5", ms=10, label="ball at the start")
    ax.plot(*ball1[:2], "o", color="tab:orange", ms=10, label="ball after its move")
    finish_footsteps_axes(ax)
    ax.set_title(f"grasp-walk: footsteps planned vs executed ({len(rec.plans)} plans)")
    paths.append(save_figure(fig, out_dir / "footsteps.png"))

    # 2. CoM and ZMP along x and y (fig. 2.16): reference ZMP, measured ZMP, CoM reference and
    # measured CoM; plan arrivals and the ball's move marked.
    st = [s for s in rec.statuses if np.all(np.isfinite(s.zmp_measured))]
    t = np.array([s.utime for s in st]) * 1e-6
    fig, axes = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, [s.zmp_measured[k] for s in st], lw=0.7, color="tab:red", label="ZMP measured")
        ax.plot(t, [s.zmp_reference[k] for s in st], lw=1.2, color="k", label="ZMP reference")
        ax.plot(t, [s.com[k] for s in st], lw=1.2, color="tab:blue", label="CoM reference")
        ax.plot(t_q, com[:, k], "--", lw=1, color="tab:green", label="CoM measured")
        for u, _ in rec.plans:
            ax.axvline(u * 1e-6, color="0.85", lw=0.6)
        ax.axvline(utime_move * 1e-6, color="tab:orange", lw=1.2, label="ball starts moving")
        ax.set_ylabel(f"{'xy'[k]} [m]")
        ax.set_xlabel("controller time [s] (grey: footstep plans received)")
    axes[0].legend(fontsize=7, ncol=5)
    fig.suptitle("grasp-walk: CoM and ZMP (Dang 2012 fig. 2.16)")
    paths.append(save_figure(fig, out_dir / "com_zmp.png"))

    # 3. ZMP margin inside the loaded soles' polygon over time.
    m = zmp_margins(rec.statuses, rec.loaded, half)
    fig, ax = plt.subplots(figsize=(11, 3))
    ax.plot(m[:, 0], 1e3 * m[:, 1], lw=0.7)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("controller time [s]")
    ax.set_ylabel("ZMP margin [mm]")
    ax.set_title("measured ZMP: distance inside the support polygon of the loaded soles")
    paths.append(save_figure(fig, out_dir / "zmp_margin.png"))
    return paths


SCENARIO = GraspWalk(
    name="grasp-walk",
    description="TALOS walks to a ball moved sideways while it walks; the footstep process "
    "replans, the controller walks the new steps (thesis 001 ch. 6, no final grasp)",
    seed_experiment="thesis 001 ch. 6 (walking to a ball moved while the robot walks, §6.3)",
    robot=ROBOT,
    scene=robots.robot(ROBOT).mjcf,
    seed=0,
)
