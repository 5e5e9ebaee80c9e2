"""pink 4.4 (+ daqp) on the TALOS reference stack of bench/sot, in closed loop at 1 kHz.

Runs in .venv-bench (bench/sot_peers/setup_venv.sh), never in the product's venv. pink is a
velocity-level IK: one weighted QP over Δq = v dt with hard equality constraints and the joint
limits as inequalities. The stack of marionette-bench-sot maps onto it as
  hard equality constraints (pink's `constraints`): left foot 6D, right foot 6D, CoM 3D (λ 10/s)
  limits: pink's default ConfigurationLimit (gain 0.5 per tick = our λ_l dt = 500/s · 1 ms) and
          VelocityLimit (the URDF velocity limits, as ours)
  costs: right gripper 6D (λ 1/s, weight 1), left gripper relative to right 6D
         (RelativeFrameTask, λ 1/s, weight 1), posture 32D (λ 1/s, weight --posture-weight,
         default 1e-5 as for TSID: see tsid_bench.cc)
pink's task gain α is the fraction of the error removed per step (J Δq = -α e), so α = λ dt; its
cost c enters squared (c² ||J Δq + α e||²), so c = sqrt(weight) gives TSID's weights. Two
priorities cannot express three equality levels: grippers over posture is a weight ratio.

Timed per tick: configuration.update(q) (pink's kinematics: computeJointJacobians +
updateFramePlacements) and solve_ik (tasks, limits, QP build and daqp through qpsolvers) — the
whole per-tick path a pink user runs. daqp is given the previous solution as initial guess
(`initvals`; qpsolvers' daqp backend does not use it, so daqp cold-starts, which is its normal
use here). The integration and the error read-outs are not timed. Python interpreter overhead is
part of pink's cost: pink has no C++ API.

    python pink_bench.py --urdf U --srdf S [--ticks N] [--reach x y z] [--scenario NAME]
prints one JSON object {"<scenario>": {...}}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

import numpy as np
import pinocchio as pin

DT = 1e-3  # the 1 kHz tick of marionette-bench-sot
RIGHT_GRIPPER = "gripper_right_base_link"
LEFT_GRIPPER = "gripper_left_base_link"


def summarize(samples_s: list[float]) -> dict[str, float]:
    """Median, p90, p99 and max of durations given in seconds, in µs (same quantile rule as C++)."""
    v = np.sort(np.asarray(samples_s) * 1e6)
    at = lambda q: float(v[int(q * (len(v) - 1))])  # noqa: E731
    return {"median": at(0.5), "p90": at(0.9), "p99": at(0.99), "max": float(v[-1])}


def run(args: argparse.Namespace) -> dict:
    """Runs the warm-up and the timed ticks; returns the scenario's figures."""
    import pink
    from pink.tasks import ComTask, FrameTask, PostureTask, RelativeFrameTask

    model = pin.buildModelFromUrdf(args.urdf, pin.JointModelFreeFlyer())
    pin.loadReferenceConfigurations(model, args.srdf, False)
    q = model.referenceConfigurations["half_sitting"].copy()
    data = model.createData()
    configuration = pink.Configuration(model, data, q)

    def frame_task(frame: str, lam: float, weight: float) -> FrameTask:
        c = float(np.sqrt(weight))
        return FrameTask(frame, position_cost=c, orientation_cost=c, gain=lam * DT)

    left_foot = frame_task("left_sole_link", 10.0, 1.0)
    right_foot = frame_task("right_sole_link", 10.0, 1.0)
    com = ComTask(cost=1.0, gain=10.0 * DT)
    right_hand = frame_task(RIGHT_GRIPPER, 1.0, 1.0)
    left_hand = RelativeFrameTask(
        LEFT_GRIPPER, RIGHT_GRIPPER, position_cost=1.0, orientation_cost=1.0, gain=1.0 * DT
    )
    posture = PostureTask(cost=float(np.sqrt(args.posture_weight)), gain=1.0 * DT)
    for task in (left_foot, right_foot, com, left_hand, posture):
        task.set_target_from_configuration(configuration)
    target = configuration.get_transform_frame_to_world(RIGHT_GRIPPER).copy()
    target.translation = target.translation + np.asarray(args.reach)
    right_hand.set_target(target)
    constraints = [left_foot, right_foot, com]
    costs = [right_hand, left_hand, posture]

    failures = 0
    max_foot_error = 0.0
    v = np.zeros(model.nv)
    t_update, t_solve, t_tick = [], [], []

    def tick(timed: bool) -> None:
        nonlocal q, v, failures, max_foot_error
        t0 = time.perf_counter()
        configuration.update(q)
        t1 = time.perf_counter()
        try:
            # solve_ik returns the velocity v = Δq / dt; daqp's initial guess is the last Δq.
            v = pink.solve_ik(
                configuration,
                costs,
                DT,
                solver="daqp",
                constraints=constraints,
                safety_break=False,
                initvals=v * DT,
            )
        except pink.exceptions.NoSolutionFound:
            failures += 1
            v = np.zeros(model.nv)
        t2 = time.perf_counter()
        if timed:
            t_update.append(t1 - t0)
            t_solve.append(t2 - t1)
            t_tick.append(t2 - t0)
            max_foot_error = max(
                max_foot_error,
                float(np.linalg.norm(left_foot.compute_error(configuration))),
                float(np.linalg.norm(right_foot.compute_error(configuration))),
            )
        q = pin.integrate(model, q, v * DT)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # qpsolvers: "daqp does not support initvals" once
        for _ in range(500):  # warm-up, as marionette-bench-sot
            tick(timed=False)
        failures = 0
        for _ in range(args.ticks):
            tick(timed=True)
    configuration.update(q)
    hand_error = float(
        np.linalg.norm(
            configuration.get_transform_frame_to_world(RIGHT_GRIPPER).translation
            - target.translation
        )
    )
    return {
        "ticks": args.ticks,
        "qp": "daqp (qpsolvers)",
        "posture_weight": args.posture_weight,
        "qp_failures": failures,
        "final_hand_position_error": hand_error,
        "max_foot_error": max_foot_error,
        "kinematics": summarize(t_update),
        "solve": summarize(t_solve),
        "tick": summarize(t_tick),
        "versions": {"pink": pink.__version__, "pinocchio": pin.__version__},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--urdf", required=True)
    parser.add_argument("--srdf", required=True)
    parser.add_argument("--ticks", type=int, default=20000)
    parser.add_argument("--reach", type=float, nargs=3, default=[0.10, -0.05, 0.10])
    parser.add_argument("--scenario", default="nominal")
    parser.add_argument("--posture-weight", type=float, default=1e-5)
    args = parser.parse_args(argv)
    if args.ticks < 10000:
        parser.error(f"--ticks must be >= 10000 (got {args.ticks})")
    if not args.posture_weight > 0.0:
        parser.error(f"--posture-weight must be > 0 (got {args.posture_weight})")
    print(json.dumps({args.scenario: run(args)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
