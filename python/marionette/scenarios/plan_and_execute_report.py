"""The report folder of a plan-and-execute trial: report.json (success, criteria with measured
values, timings, per-step records), report.md (the same for people) and PNG plots: task errors per
step, one panel per unit (the decay of fig. 5.4, :mod:`.task_error_plot`), planned vs executed
joints and object path, CoM vs support polygon (humanoids)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.scenarios.report import (
    controller_and_plots_lines,
    save_figure,
    speed_text,
    timings_lines,
    title,
    write_json,
    write_report_files,
)
from marionette.scenarios.task_error_plot import (
    StepTasks,
    configuration_units,
    plot_task_errors,
    split_by_unit,
)


def _records(result) -> list[dict[str, Any]]:
    out = []
    for r in result.records:
        out.append(
            {
                "index": r.index,
                "transition": r.transition,
                "kind": r.kind,
                "result": r.result,
                "controller_id": r.controller_id,
                "planned_duration_s": r.duration_s,
                "controller_time_s": (r.utime_end - r.utime_start) * 1e-6 if r.utime_end else None,
                "wall_s": r.wall_s,
                "chunks": r.chunks,
                "retimed": r.retimed,
                "retimed_for": r.retimed_for,
                "lean_rad": r.lean,
                "switch_retries": r.switch_retries,
                "min_lookahead_ms": r.min_lookahead_ms,
                "max_task_errors": r.max_errors,
                "final_task_errors": r.final_errors,
                "events": r.events,
            }
        )
    return out


def write_report(
    out_dir: Path, report: dict[str, Any], scenario, supervisor, result, recorder, model: pin.Model
) -> None:
    report["steps"] = _records(result)
    write_report_files(
        out_dir,
        report,
        lambda: _plots(out_dir, scenario, supervisor, result, recorder, model),
        _markdown,
    )


def write_refusal(out_dir: Path, report: dict[str, Any]) -> None:
    """report.json and report.md of a trial stopped before anything moved (``report["stopped"]``
    says why): the dry run's verdict per step and the calibration, when they ran."""
    write_json(out_dir / "report.json", report)
    lines = [
        f"# Demo `{report['scenario']}` — FAILURE (stopped before execution)",
        "",
        report.get("description", ""),
        "",
        f"seed {report['seed']}, robot {report['robot']}: {report['stopped']}",
        "",
    ]
    lines += _dry_run_lines(report) + _calibration_lines(report)
    if "timings" in report:
        lines += timings_lines(report["timings"])
    (out_dir / "report.md").write_text("\n".join(lines) + "\n")


def _dry_run_lines(r: dict[str, Any]) -> list[str]:
    """## Dry run: the verdict per step (marionette.execution.dry_run)."""
    d = r.get("dry_run")
    if d is None:
        return []
    lines = [
        "## Dry run (before anything moved)",
        "",
        f"The generated controllers played on the plan on the {d['backend']} controller: "
        f"{'passed' if d['ok'] else 'REFUSED: ' + d['reason']} ({d['wall_s']:.1f} s wall, "
        f"{d['controller_s']:.1f} s of controller time; supervisor {d['supervisor']}). "
        "Smallest singular value any level needs along the step (the controller damps below "
        "0.02), the switch, the end check, and the largest distance of a joint from its streamed "
        "reference (the IK branch). Static load: the largest gravity torque a joint bears along "
        "the step (its links and what a gripper carries alone) over its effort limit; the legs, "
        "loaded by the ground, are not judged.",
        "",
        "| # | transition | min singular value | static load | switch | converged | joint "
        "deviation | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in d["steps"]:
        sv = s["min_singular_value"]
        sigma = "-" if sv is None else f"{sv:.3f} ({s['singular_level']})"
        conv = {None: "-", True: f"yes, {s['controller_s']:.1f} s", False: "no"}[s["converged"]]
        dev = f"{s['max_joint_deviation']:.3f} rad ({s['deviation_joint']})" if s["played"] else "-"
        load = s.get("static_load")
        load_text = "-" if load is None else f"{load:.2f} ({s['static_load_joint']})"
        verdict = "ok" if s["ok"] else "; ".join(s["reasons"])
        if s["ok"] and not s["played"]:
            verdict = "not reached"
        lines.append(
            f"| {s['index']} | `{s['transition']}` | {sigma} | {load_text} | {s['switch'] or '-'} "
            f"| {conv} | "
            f"{dev} | {verdict} |"
        )
    return [*lines, ""]


def _calibration_lines(r: dict[str, Any]) -> list[str]:
    """## Encoder calibration: the arms' offsets from the head camera, before execution."""
    if "calibration" not in r:
        return []
    lines = [
        "## Encoder calibration (thesis 000 ch. 4.2)",
        "",
        "Wrist rings seen by the head camera; the controller runs with the offsets found. Error = "
        "found − the perturbation's offset.",
        "",
        "| arm | views used | rounds | residual | offsets found | worst error |",
        "|---|---|---|---|---|---|",
    ]
    for a in r["calibration"]["arms"]:
        worst = max(a["error_deg"].items(), key=lambda kv: abs(kv[1]))
        lines.append(
            f"| {a['side']} | {a['views_used']}/{a['views_planned']} | {a.get('rounds', 1)} | "
            f"{a['residual_position_mm']:.2f} mm / {a['residual_rotation_deg']:.2f}° | "
            + ", ".join(
                f"{j.split('_')[2]}: {v:+.2f}°" for j, v in a["encoder_offsets_deg"].items()
            )
            + f" | {worst[1]:+.3f}° ({worst[0]}) |"
        )
    return [*lines, ""]


def _markdown(r: dict[str, Any]) -> str:
    c = r["criteria"]
    lines = [
        title(r),
        "",
        r.get("description", ""),
        "",
        f"seed {r['seed']}, robot {r['robot']}, {speed_text(r['speed'])}, "
        f"supervisor: {r['supervisor']['state']}"
        + (f" ({r['supervisor']['reason']})" if r["supervisor"]["reason"] else ""),
        "",
        "## Success criteria (docs/scenarios.md)",
        "",
        "| criterion | measured | limit | ok |",
        "|---|---|---|---|",
        f"| object position error | {c['object_position_error_m'] * 1e3:.1f} mm | "
        f"{c['limits']['position_m'] * 1e3:.0f} mm | {c['object_within_tolerance']} |",
        f"| object angle error | {c['object_angle_error_deg']:.2f}° | "
        f"{c['limits']['angle_deg']}° | {c['object_within_tolerance']} |",
    ]
    if "feet_max_displacement_m" in c:
        lines += [
            f"| feet displacement (max) | {c['feet_max_displacement_m'] * 1e3:.2f} mm | "
            f"{c['limits']['feet_m'] * 1e3:.0f} mm | {c['feet_never_moved']} |",
            f"| base height drop (max) | {c['base_max_drop_m'] * 1e3:.1f} mm | planned "
            f"{c.get('base_planned_drop_m', 0.0) * 1e3:.1f} + 50 mm | {c['no_fall']} |",
        ]
    if "grip_within_tolerance" in c:
        medians = [
            h.get("contact_median_n") for g in r["grip"]["grippers"].values() for h in g["held"]
        ]
        shown = (
            ", ".join("never switched" if m is None else f"{m:.2f} N" for m in medians) or "no hold"
        )
        lines += [
            f"| grip force on the jaws (median per hold) | {shown} | "
            f"{r['grip']['target_n']:.0f} ± {c['limits']['grip_n']:.0f} N | "
            f"{c['grip_within_tolerance']} |"
        ]
    lines += [f"| FSM reached `done` | {r['supervisor']['state']} | done | {c['fsm_done']} |", ""]
    if "perturbation" in r:
        p = r["perturbation"]
        lines += [
            "## Perturbations (seeded)",
            "",
            f"object displaced before execution by ({p['displacement_mm_deg'][0]:.1f} mm, "
            f"{p['displacement_mm_deg'][1]:.1f} mm, {p['displacement_mm_deg'][2]:.1f}°); "
            "slip in the hand "
            + ("at its last carry" if p.get("slip_step") is None else f"at step {p['slip_step']}")
            + f": {np.linalg.norm(p['slip'][:3]) * 1e3:.1f} mm / "
            f"{np.degrees(np.linalg.norm(p['slip'][3:])):.1f}°; joint offsets "
            + (", ".join(f"{k} {v:+.1f}°" for k, v in p["joint_offsets_deg"].items()) or "none")
            + f"; camera noise {p['camera_noise_m'] * 1e3:.1f} mm / "
            f"{np.degrees(p['camera_noise_rad']):.2f}°"
            + (
                f"; the held object pushed with {np.linalg.norm(p['push']):.1f} N "
                f"({', '.join(f'{f:+.1f}' for f in p['push'])}) for {p['push_s']:g} s, "
                f"{p['push_delay_s']:.2f} s after its grip settled"
                if any(p.get("push", ()))
                else ""
            )
            + (
                f"; the held object's friction set to {p['carry_friction']:g} once its grip "
                "settled in its first carry"
                if p.get("carry_friction")
                else ""
            ),
            "",
        ]
    lines += _dry_run_lines(r) + _calibration_lines(r)
    if "vision" in r:
        v = r["vision"]
        lines += [
            "## Vision in the loop (thesis 000 §5.3.1)",
            "",
            f"{v['measurements_used']} object poses used, {v['measurements_rejected']} rejected, "
            f"{v.get('measurements_hand_off_command', 0)} of a held object not used: the hand the "
            "encoders measured was then off the hand the controller commanded (lagging a fast "
            "motion), or no robot state came within 20 ms of the image.",
            "",
            "Poses used: those measured during the step, and those of the object at rest "
            "measured before an approach to it (the reaching hand may hide it).",
            "",
            "| step | poses used | last measured object error | correction |",
            "|---|---|---|---|",
        ]
        used = v.get("used_per_step", {})
        lines += [
            f"| {k} | {_poses_used(used.get(k))} | "
            f"{t['object_error_m'] * 1e3:.1f} mm / {t['object_error_deg']:.2f}° | "
            f"{t['correction_m'] * 1e3:.1f} mm / {t['correction_deg']:.2f}° |"
            for k, t in v["last_per_step"].items()
        ]
        lines += [""]
    if "grip" in r:  # the grip force the admittance holds, measured on the contacts
        g = r["grip"]
        lines += [
            "## Gripper admittance (thesis 000 §3.2.4.3)",
            "",
            f"target {g['target_n']:.1f} N; contact = MuJoCo contact forces on the jaws, "
            "estimate = joint effort through eq. 3.11-3.13; from 1 s after the switch to "
            "admittance to the release; the object's motion in the hand = the largest "
            "displacement and turn of its pose in the gripper's link over that window "
            "(simulator's truth).",
            "",
            "| gripper | window [s] | contact median (min-max) | estimate mean | "
            "estimate - contact, median | object's motion in the hand |",
            "|---|---|---|---|---|---|",
        ]
        for name, d in g["grippers"].items():
            for h in d["held"] or [{"never_switched": True}]:
                if "contact_median_n" not in h:
                    lines.append(
                        f"| {name} | - | never switched to admittance or no contact measured "
                        "| - | - | - |"
                    )
                    continue
                lines.append(
                    f"| {name} | {h['t_from_s']:.1f}-{h['t_to_s']:.1f} | "
                    f"{h['contact_median_n']:.2f} N ({h['contact_min_n']:.2f}-"
                    f"{h['contact_max_n']:.2f}) | {h['estimate_mean_n']:.2f} N | "
                    f"{h['estimate_minus_contact_median_n']:+.2f} N | "
                    + (
                        f"{h['object_motion_mm']:.2f} mm, {h['object_rotation_deg']:.2f}° |"
                        if "object_motion_mm" in h
                        else "not measured (no simulator) |"
                    )
                )
        lines += ["", f"![{g['plot']}]({g['plot']})", ""]
    lines += [
        "## Estimation (§3.2.2)",
        "",
        f"state `{r['estimation']['state']}`, projection residual "
        f"{r['estimation']['residual']:.2e}, started at step {r['estimation']['first_step']}",
        "",
        *timings_lines(r["timings"]),
    ]
    lines += [
        "",
        "## Steps (one controller each)",
        "",
        "Re-timed: how much slower than its time law a step was played for its rewritten "
        "references (the gaze) to respect the joints' velocity bounds, and the joint that asked. "
        "Lean: how far a servoed step leaned the torso for the head camera to see the object.",
        "",
        "| # | transition | kind | planned s | re-timed | lean rad | controller s | wall s "
        "| switch retries | min look-ahead ms | result |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in r["steps"]:
        ct = f"{s['controller_time_s']:.2f}" if s["controller_time_s"] is not None else "-"
        la = f"{s['min_lookahead_ms']:.0f}" if s["min_lookahead_ms"] is not None else "-"
        rt = f"x{s['retimed']:.2f} ({s['retimed_for']})" if s.get("retimed", 1.0) > 1.0 else "-"
        lines.append(
            f"| {s['index']} | `{s['transition']}` | {s['kind']} | {s['planned_duration_s']:.2f} | "
            f"{rt} | {s.get('lean_rad', 0.0):.2f} | {ct} | {s['wall_s']:.2f} | "
            f"{s.get('switch_retries', 0)} | {la} | "
            f"{s['result']} |"
        )
    lines += controller_and_plots_lines(r)
    lines += [
        "",
        "Files: `controllers.yaml` (the generated controllers), `run.lcmlog` (every LCM "
        "message of the run: `marionette replay run.lcmlog --view` plays it in the browser, "
        "`--controller` / `--supervisor` re-run the controller / the supervisor's decisions "
        "from it), `logs/` (process outputs).",
    ]
    return "\n".join(lines) + "\n"


def run_task_steps(records: list, supervisor) -> list[StepTasks]:
    """The steps of a live run for :func:`split_by_unit`: each record's error trace, the tasks of
    its step's spec and the references streamed to them (the step's sampled trajectory)."""
    specs = {s.index: sp for s, sp in zip(supervisor.steps, supervisor.specs)}
    out = []
    for r in records:
        spec = specs.get(r.index)
        traj = supervisor.trajectories.get(r.index)
        references = {}
        if traj is not None and r.utime_reference_start:
            t = traj.t + r.utime_reference_start * 1e-6
            references = {name: (t, values) for name, (values, _) in traj.references.items()}
        tasks = {t.name: t for t in spec.tasks} if spec is not None else {}
        out.append(StepTasks(r.error_trace, tasks, references))
    return out


def _plots(
    out_dir: Path,
    scenario,
    supervisor,
    result,
    recorder,
    model: pin.Model,
    task_steps: list[StepTasks] | None = None,
) -> list[Path]:
    """The report's plots; ``task_steps`` (default: from ``supervisor``) for the task errors."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths: list[Path] = []
    t_rec = np.array(recorder.utimes) * 1e-6
    q_rec = np.array(recorder.q) if recorder.q else np.zeros((0, model.nq))

    # 1. Task errors per step (fig. 5.4-like decay), one panel per unit, step boundaries marked.
    if task_steps is None:
        task_steps = run_task_steps(result.records, supervisor)
    fig = plot_task_errors(
        split_by_unit(task_steps, model, t_rec, q_rec),
        [r.utime_start * 1e-6 for r in result.records if r.error_trace],
        f"{scenario.name}: task errors by unit, one controller per step (grey lines: switches)\n"
        "(measured): forward kinematics of the recorded robot state vs the task's reference; "
        "others: the controller's ||e||",
    )
    paths.append(save_figure(fig, out_dir / "task_errors.png"))

    # 2. Planned vs executed joints (the 6 that move most) and object path.
    plan_t: list[np.ndarray] = []
    plan_q: list[np.ndarray] = []
    plan_obj: list[tuple[np.ndarray, np.ndarray]] = []  # (times, object positions)
    for r in result.records:
        traj = supervisor.trajectories.get(r.index)
        if traj is None or not r.utime_reference_start:
            continue
        plan_t.append(traj.t + r.utime_reference_start * 1e-6)
        plan_q.append(traj.q)
        positions = np.array(
            [
                supervisor.robot_map.object_pose(q, scenario.object_name).translation
                for q in traj.q_plan[::20]
            ]
        )
        plan_obj.append((plan_t[-1][::20], positions))
    if plan_t:
        pt, pq = np.concatenate(plan_t), np.vstack(plan_q)
        first_joint = 7 if model.joints[1].nq == 7 else 0
        motion = np.ptp(pq[:, first_joint:], axis=0)
        top = first_joint + np.argsort(motion)[::-1][:6]
        fig, axes = plt.subplots(2, 3, figsize=(12, 6), sharex=True)
        labels = [n for j in range(1, model.njoints) for n in [model.names[j]] * model.joints[j].nq]
        units = configuration_units(model)
        for ax, k in zip(axes.flat, top):
            ax.plot(pt, pq[:, k], "k--", lw=1, label="planned")
            if len(q_rec):
                ax.plot(t_rec, q_rec[:, k], lw=1, label="executed")
            name = labels[k] if k < len(labels) else f"q[{k}]"
            ax.set_ylabel(f"{name} [{units[k]}]", fontsize=8)
            ax.set_xlabel("controller time [s]")
        axes.flat[0].legend(fontsize=7)
        fig.suptitle(f"{scenario.name}: planned vs executed joints (the 6 that move most)")
        paths.append(save_figure(fig, out_dir / "joints.png"))

        fig, axes = plt.subplots(3, 1, figsize=(10, 6), sharex=True)
        ot = np.concatenate([t for t, _ in plan_obj])
        op = np.vstack([p for _, p in plan_obj])
        ex = (
            np.array(
                [
                    o[scenario.object_name][:3] if scenario.object_name in o else [np.nan] * 3
                    for o in recorder.objects
                ]
            )
            if recorder.objects
            else np.zeros((0, 3))
        )
        for i, ax in enumerate(axes):
            ax.plot(ot, op[:, i], "k--", lw=1, label="planned")
            if len(ex):
                ax.plot(t_rec, ex[:, i], lw=1, label="executed (simulator)")
            ax.set_ylabel(f"{'xyz'[i]} [m]")
            ax.set_xlabel("controller time [s]")
        axes[0].legend(fontsize=7)
        fig.suptitle(f"{scenario.name}: {scenario.object_name} position, planned vs executed")
        paths.append(save_figure(fig, out_dir / "object_path.png"))

    # 3. CoM vs support polygon (humanoid).
    if scenario.feet and len(q_rec):
        data = model.createData()
        com = np.array([pin.centerOfMass(model, data, q)[:2] for q in q_rec[::4]])
        pin.framesForwardKinematics(model, data, q_rec[0])
        sem = robots.semantics(supervisor.robot_map.robot)
        corners: list[np.ndarray] = []
        for c in sem.contacts:
            X = data.oMf[model.getFrameId(c.link)]
            corners += [X.act(np.asarray(p, dtype=float))[:2] for p in c.points]
        pts = np.array(corners)
        fig, ax = plt.subplots(figsize=(6, 6))
        if len(pts) >= 3:
            from scipy.spatial import ConvexHull

            hull = pts[ConvexHull(pts).vertices]
            ax.fill(hull[:, 0], hull[:, 1], alpha=0.2, label="support polygon")
        if plan_t:
            data2 = model.createData()
            pcom = np.array([pin.centerOfMass(model, data2, q)[:2] for q in pq[::50]])
            ax.plot(pcom[:, 0], pcom[:, 1], "k--", lw=1, label="planned CoM")
        ax.plot(com[:, 0], com[:, 1], lw=1, label="executed CoM")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.legend(fontsize=7)
        ax.set_title(f"{scenario.name}: CoM over the support polygon")
        paths.append(save_figure(fig, out_dir / "com_support.png"))
    return paths


def _poses_used(counts: list[int] | None) -> str:
    """ "12", or "12 (3 at rest before)" when some were seen before the step."""
    if not counts:
        return "-"
    n, at_rest = counts
    return f"{n} ({at_rest} at rest before)" if at_rest else str(n)
