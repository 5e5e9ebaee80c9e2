"""``marionette perceive`` and ``marionette calibrate`` (thin: parsing and wiring only)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np


def _default_object_files() -> list[Path]:
    from marionette import MODELS_DIR

    return sorted(p for p in (MODELS_DIR / "objects").glob("*.yaml") if "tags:" in p.read_text())


def _up_axis(text: str) -> tuple[str, np.ndarray]:
    try:
        name, axis = text.split(":")
        vector = np.array([float(a) for a in axis.split(",")])
        if vector.shape != (3,) or not np.linalg.norm(vector) > 0:
            raise ValueError
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME:X,Y,Z, got {text!r}") from None
    return name, vector


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "perceive",
        help="detect AprilTags in camera frames, publish tag detections and object poses",
        description="Subscribes CAMERA_HEAD (and ROBOT_STATE); publishes APRILTAG_DETECTIONS and "
        "OBJECT_POSES at camera rate.",
        epilog=(
            "examples:\n"
            "  marionette perceive --robot talos\n"
            "  marionette perceive --robot none --camera-pose-source message"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--lcm-url", default=None, help="LCM URL (default: $MARIONETTE_LCM_URL)")
    p.add_argument(
        "--objects",
        nargs="*",
        type=Path,
        default=None,
        help="object YAML files with tags (default: every models/objects/*.yaml with tags)",
    )
    p.add_argument(
        "--robot",
        required=True,
        help="robot (name or folder) whose kinematics place the camera, or 'none'",
    )
    p.add_argument("--camera-frame", default=None, help="optical frame (default: the robot's)")
    p.add_argument("--camera-channel", default=None, help="image channel (default CAMERA_HEAD)")
    p.add_argument(
        "--camera-pose-source",
        choices=("kinematics", "message"),
        default=None,
        help="world pose of the camera: robot kinematics (default with a robot) or the "
        "simulator's pose in the image message",
    )
    p.add_argument("--no-depth", action="store_true", help="ignore depth (image-only poses)")
    p.add_argument(
        "--quad-decimate",
        type=float,
        default=None,
        help="AprilTag quad decimation (default 2: quads on a half-size image; 1 finds "
        "tags of ~40 px, e.g. a tool's 3 cm tags at 0.7 m, at about twice the cost)",
    )
    p.add_argument(
        "--full-search-every",
        type=int,
        default=None,
        metavar="N",
        help="search the whole image every N frames and around the last frame's tags in "
        "between (default 10; 1: the whole image every frame)",
    )
    p.add_argument(
        "--up-axis",
        action="append",
        type=_up_axis,
        default=[],
        metavar="NAME:X,Y,Z",
        help="prior: body NAME rests with this axis up (resolves ambiguous tags)",
    )
    p.add_argument(
        "--max-position-sigma",
        type=float,
        default=None,
        metavar="METRES",
        help="publish a body's pose only when its origin is known to within this (1 sigma from "
        "the tag corners; e.g. 0.005: a long bar seen by one end tag is not published)",
    )
    p.add_argument(
        "--max-tilt-deg",
        type=float,
        default=None,
        metavar="DEG",
        help="publish a body given --up-axis only when its estimate tilts that axis by at most "
        "this from the vertical (a resting body does not tilt; a wrong single-tag estimate does)",
    )
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--stats-period", type=float, default=5.0, help="print statistics every s")
    p.set_defaults(func=_perceive)

    c = subparsers.add_parser(
        "calibrate",
        help="hand-eye, joint-offset or arm-encoder calibration",
        description="Prints the calibration as JSON: from recorded measurements (hand-eye, "
        "joint-offsets) or from the head camera in a MuJoCo scene (arm-encoders).",
        epilog=(
            "examples:\n"
            "  marionette calibrate arm-encoders --scene models/scenes/talos_plank.xml"
            " --side left\n"
            "  marionette calibrate hand-eye measurements.json"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = c.add_subparsers(dest="calibration", required=True, metavar="KIND")
    he = sub.add_parser("hand-eye", help="camera mount from (robot pose, target pose) pairs")
    he.add_argument(
        "measurements",
        type=Path,
        help='JSON {"X_RE": [4x4...], "X_CT": [4x4...]} (eye-in-hand; for a head '
        "camera and a target in the hand pass X_HG as X_RE, see calibration.py)",
    )
    he.set_defaults(func=_calibrate_hand_eye)
    jo = sub.add_parser(
        "joint-offsets", help="encoder offsets by simultaneous projection (ch. 4.2)"
    )
    jo.add_argument(
        "measurements",
        type=Path,
        help='JSON {"robot": NAME, "base_frame": ..., "marker_frame": ..., '
        '"joints": [...], "configurations": [[q...]], "positions": [[x,y,z]...]}',
    )
    jo.set_defaults(func=_calibrate_joint_offsets)
    ae = sub.add_parser(
        "arm-encoders",
        help="a robot's arm encoder offsets from its wrist tags seen by the head "
        "camera in a MuJoCo scene (ch. 4.2; the arms of robot.yaml's calibration section)",
    )
    ae.add_argument(
        "--scene", type=Path, required=True, help="MJCF scene with the robot (and its encoders)"
    )
    ae.add_argument(
        "--robot",
        default=None,
        help="robot name or folder (default: the robot of the scene's YAML beside it)",
    )
    ae.add_argument(
        "--side",
        action="append",
        help="arm to calibrate (repeatable; default every arm of the calibration section)",
    )
    ae.add_argument("--seed", type=int, default=0, help="seed of the view sampling and image noise")
    ae.set_defaults(func=_calibrate_arm_encoders)


def _perceive(args: argparse.Namespace) -> int:
    from marionette import robots
    from marionette.lcm_bus import LcmBus
    from marionette.perception.kinematics import CameraKinematics
    from marionette.perception.node import PerceptionConfig, PerceptionNode
    from marionette.perception.objects import (
        check_unique_ids,
        load_tagged_bodies,
        tagged_bodies_from_semantics,
    )
    from marionette.perception.tracking import TrackingConfig

    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s", stream=sys.stderr)
    files = args.objects if args.objects is not None else _default_object_files()
    bodies = load_tagged_bodies(files)
    kinematics = None
    if args.robot != "none":
        model, _ = robots.load_pinocchio(args.robot, with_collision=False)
        frame = args.camera_frame or robots.robot(args.robot).camera_frame
        if frame is None:
            print(
                f"marionette perceive: robot {args.robot} has no camera frame; pass "
                "--camera-frame or add one to its robot.yaml",
                file=sys.stderr,
            )
            return 1
        kinematics = CameraKinematics(model, frame)
        robot_sem = robots.semantics(args.robot)
        if robot_sem.tags:  # e.g. wrist tags, for the measured gripper pose of PBVS
            bodies += tagged_bodies_from_semantics(robot_sem)
            check_unique_ids(bodies)
    source = args.camera_pose_source or ("kinematics" if kinematics else "message")
    config = PerceptionConfig(
        bodies=bodies,
        use_depth=not args.no_depth,
        camera_pose_source=source,
        up_axes=dict(args.up_axis),
    )
    if args.quad_decimate is not None:
        if not args.quad_decimate >= 1.0:
            print(
                f"marionette perceive: --quad-decimate must be >= 1, got {args.quad_decimate}",
                file=sys.stderr,
            )
            return 2
        config.detector.quad_decimate = args.quad_decimate
    if args.max_position_sigma is not None:
        if not (math.isfinite(args.max_position_sigma) and args.max_position_sigma > 0.0):
            print(
                "marionette perceive: --max-position-sigma must be a positive number of metres, "
                f"got {args.max_position_sigma}",
                file=sys.stderr,
            )
            return 2
        config.max_position_sigma = args.max_position_sigma
    if args.max_tilt_deg is not None:
        if not (math.isfinite(args.max_tilt_deg) and 0.0 < args.max_tilt_deg < 180.0):
            print(
                "marionette perceive: --max-tilt-deg must be a number of degrees in (0, 180), "
                f"got {args.max_tilt_deg}",
                file=sys.stderr,
            )
            return 2
        if not args.up_axis:
            print(
                "marionette perceive: --max-tilt-deg needs --up-axis (which axis of which body "
                "should point up)",
                file=sys.stderr,
            )
            return 2
        config.max_tilt_deg = args.max_tilt_deg
    if args.full_search_every is not None:
        if args.full_search_every < 1:
            print(
                "marionette perceive: --full-search-every must be >= 1, got "
                f"{args.full_search_every}",
                file=sys.stderr,
            )
            return 2
        config.tracking = TrackingConfig(full_search_every=args.full_search_every)
    if args.camera_channel:
        config.camera_channel = args.camera_channel
    node = PerceptionNode(config, kinematics)
    bus = LcmBus(args.lcm_url)
    node.attach(bus)
    bus.start()
    print(
        f"perceive: {len(bodies)} tagged bodies ({', '.join(b.name for b in bodies)}), "
        f"camera pose from {source}, listening on {config.camera_channel}",
        flush=True,
    )
    start = last_print = time.monotonic()
    try:
        while True:
            node.step(timeout_s=0.1)
            now = time.monotonic()
            if args.max_frames is not None and node.counters["frames_processed"] >= args.max_frames:
                break
            if args.duration is not None and now - start >= args.duration:
                break
            if now - last_print >= args.stats_period:
                print(f"perceive: {json.dumps(node.stats())}", flush=True)
                last_print = now
    except KeyboardInterrupt:
        pass
    finally:
        bus.stop()
    print(f"perceive: final {json.dumps(node.stats())}", flush=True)
    return 0


def _load_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SystemExit(f"calibrate: cannot read {path}: {exc}") from None


def _calibrate_hand_eye(args: argparse.Namespace) -> int:
    from marionette.perception.calibration import calibrate_hand_eye

    data = _load_json(args.measurements)
    import pinocchio as pin

    X_RE = [pin.SE3(np.asarray(M, float)) for M in data["X_RE"]]
    X_CT = [pin.SE3(np.asarray(M, float)) for M in data["X_CT"]]
    result = calibrate_hand_eye(X_RE, X_CT)
    print(
        json.dumps(
            {
                "X_EC": result.X_EC.homogeneous.tolist(),
                "rms_position_m": result.rms_position,
                "rms_rotation_deg": float(np.degrees(result.rms_rotation)),
            },
            indent=2,
        )
    )
    return 0


def _calibrate_arm_encoders(args: argparse.Namespace) -> int:
    from marionette import robots
    from marionette.perception.arm_calibration import calibrate_arm, encoder_offsets_argument
    from marionette.perception.calibration import CalibrationError

    if not args.scene.is_file():
        raise SystemExit(f"calibrate: no scene file {args.scene}")
    robot = args.robot
    if robot is None:
        from marionette.models.scenes import load_scene

        declaration = args.scene.with_suffix(".yaml")
        if not declaration.is_file():
            raise SystemExit(f"calibrate: no {declaration} to name the robot: give --robot")
        robot = load_scene(declaration).robot
    sides = args.side or [a.side for a in robots.robot(robot).calibrated_arms]
    try:
        arms = [
            calibrate_arm(
                args.scene,
                side,
                robot,
                seed=args.seed,
                log=lambda line: print(line, file=sys.stderr),
            )
            for side in sides
        ]
    except CalibrationError as exc:
        raise SystemExit(f"calibrate: {exc}") from None
    offsets = {j: v for arm in arms for j, v in arm.encoder_offsets().items()}
    print(
        json.dumps(
            {
                "arms": [arm.summary() for arm in arms],
                "controller_option": "--encoder-offsets " + encoder_offsets_argument(offsets),
            },
            indent=2,
        )
    )
    return 0


def _calibrate_joint_offsets(args: argparse.Namespace) -> int:
    from marionette import robots
    from marionette.perception.calibration import JointOffsetProblem, calibrate_joint_offsets

    data = _load_json(args.measurements)
    model, _ = robots.load_pinocchio(data["robot"], with_collision=False)
    problem = JointOffsetProblem(model, data["base_frame"], data["marker_frame"], data["joints"])
    result = calibrate_joint_offsets(
        problem, np.asarray(data["configurations"], float), np.asarray(data["positions"], float)
    )
    print(
        json.dumps(
            {
                "joints": list(problem.joints),
                "offsets_deg": np.degrees(result.offsets).tolist(),
                "marker_in_end_frame": result.p_EM.tolist(),
                "marker_base_in_base_frame": result.p_BA.tolist(),
                "rms_residual_m": result.rms_residual,
                "iterations": result.iterations,
            },
            indent=2,
        )
    )
    return 0
