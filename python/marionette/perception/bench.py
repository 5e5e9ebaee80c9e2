"""Benchmark: AprilTag detection + pose per 640 x 480 frame, marionette (ViSP 3.5) against
pupil-apriltags (AprilTag 3 with its own pose) on the same synthetic frames, in one run.

    python -m marionette.perception.bench [--frames 40] [--repeats 5] [--out FILE]

Frames: 1-3 tag36h11 tags of one size (6-10 cm) at 0.5-1.5 m, 0-50 deg off-axis, either clean (like
the
MuJoCo renderer's) or with i.i.d. grey noise of 2 levels per pixel (which multiplies AprilTag's
segmentation work: every noisy 4 x 4 tile passes its contrast test). Both
detectors run single-threaded with the same AprilTag parameters, at quad_decimate 2 (AprilTag's
default: quads found on a half-size image, edges refined at full size) and 1 (full resolution,
for small far tags, where sensor noise multiplies the quad-segmentation work); calls alternate
frame by frame so that machine load hits both alike. Reported: the
median and p99 time per frame, their ratio, and each one's pose error against the rendering's
ground truth (pupil-apriltags gets the principal point in AprilTag's half-pixel convention).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from marionette.perception import synthetic as syn
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig, rotation_angle


def make_frames(n: int, K: CameraIntrinsics, noise_std: float, seed: int = 0):
    """n frames, each with a list of (tag id, size, X_CT) ground truths."""
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(n):
        tags = []
        size = rng.uniform(0.06, 0.10)  # one size per frame: one pupil-apriltags call per frame
        for k in range(rng.integers(1, 4)):
            z = rng.uniform(0.5, 1.5)
            x = (k - 1) * 0.3 * z + rng.uniform(-0.03, 0.03) * z
            y = rng.uniform(-0.15, 0.15) * z
            X = syn.look_at(
                [x, y, z],
                tilt_deg=rng.uniform(0, 50),
                tilt_axis=(rng.normal(), rng.normal(), 0.0),
                roll_deg=rng.uniform(-180, 180),
            )
            tags.append((int(10 * i + k) % 587, size, X))
        frame = syn.render(
            K,
            [syn.tag_quad(t, s, X) for t, s, X in tags],
            background=120.0,
            background_depth=2.0,
            noise_std=noise_std,
            depth_noise_std=0.002,
            rng=rng,
            supersample=3,
        )
        frames.append((frame, tags))
    return frames


def _errors(truth, found: dict[int, pin.SE3]) -> list[tuple[float, float]]:
    out = []
    for tag_id, _, X in truth:
        if tag_id in found:
            Y = found[tag_id]
            out.append(
                (
                    float(np.linalg.norm(Y.translation - X.translation)),
                    math.degrees(rotation_angle(X.rotation, Y.rotation)),
                )
            )
    return out


def run(frames, K: CameraIntrinsics, repeats: int, quad_decimate: float, noise_std: float) -> dict:
    import pupil_apriltags

    sizes = {t: s for _, truth in frames for t, s, _ in truth}
    ours = AprilTagDetector(
        DetectorConfig(tag_sizes=sizes, quad_decimate=quad_decimate, num_threads=1)
    )
    peer = pupil_apriltags.Detector(
        families="tag36h11",
        nthreads=1,
        quad_decimate=quad_decimate,
        quad_sigma=0.0,
        refine_edges=1,
        decode_sharpening=0.25,
    )
    peer_params = (K.fx, K.fy, K.cx + 0.5, K.cy + 0.5)  # AprilTag's pixel-centre convention
    names = ("marionette", "marionette_rgbd", "pupil_apriltags")
    times: dict[str, list[float]] = {name: [] for name in names}  # [s] per frame
    errors: dict[str, list[tuple[float, float]]] = {name: [] for name in names}  # [m], [deg]
    found_counts = {k: 0 for k in times}
    for r in range(repeats):
        for frame, truth in frames:
            gray = np.ascontiguousarray(frame.gray)
            t0 = time.perf_counter()
            dets = ours.detect(gray, K)
            t1 = time.perf_counter()
            rgbd = ours.detect(gray, K, depth=frame.depth)
            t2 = time.perf_counter()
            # pupil-apriltags takes one tag size per call (one size per frame here).
            peer_found = {}
            for size in sorted({s for _, s, _ in truth}):
                for d in peer.detect(
                    gray, estimate_tag_pose=True, camera_params=peer_params, tag_size=size
                ):
                    if abs(sizes.get(d.tag_id, -1) - size) < 1e-12:
                        peer_found[d.tag_id] = pin.SE3(
                            np.asarray(d.pose_R), np.asarray(d.pose_t).ravel()
                        )
            t3 = time.perf_counter()
            times["marionette"].append(t1 - t0)
            times["marionette_rgbd"].append(t2 - t1)
            times["pupil_apriltags"].append(t3 - t2)
            if r == 0:
                # pupil's tag frame is AprilTag's (z into the tag): ViSP's is x, -y, -z of it.
                flip = pin.SE3(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
                for name, found in (
                    ("marionette", {d.tag_id: d.X_CT for d in dets}),
                    ("marionette_rgbd", {d.tag_id: d.X_CT for d in rgbd}),
                    ("pupil_apriltags", {i: X * flip for i, X in peer_found.items()}),
                ):
                    errors[name] += _errors(truth, found)
                    found_counts[name] += len(found)
    n_tags = sum(len(t) for _, t in frames)
    out: dict[str, object] = {
        "frames": len(frames),
        "repeats": repeats,
        "tags": n_tags,
        "image": "640x480",
        "quad_decimate": quad_decimate,
        "noise_std": noise_std,
    }
    median_ms = {}
    for name in times:
        t = np.array(times[name]) * 1e3
        e = np.array(errors[name]) if errors[name] else np.zeros((0, 2))
        median_ms[name] = float(np.median(t))
        out[name] = {
            "median_ms": median_ms[name],
            "p99_ms": float(np.percentile(t, 99)),
            "tags_found": found_counts[name],
            "median_position_error_mm": float(np.median(e[:, 0]) * 1e3) if len(e) else None,
            "p90_position_error_mm": float(np.percentile(e[:, 0], 90) * 1e3) if len(e) else None,
            "median_rotation_error_deg": float(np.median(e[:, 1])) if len(e) else None,
            "p90_rotation_error_deg": float(np.percentile(e[:, 1], 90)) if len(e) else None,
        }
    out["ratio_median_marionette_over_pupil"] = (
        median_ms["marionette"] / median_ms["pupil_apriltags"]
    )
    return out


def _print(result: dict) -> None:
    print(
        f"AprilTag detection + pose, {result['image']}, {result['frames']} frames x "
        f"{result['repeats']} ({result['tags']} tags), single thread, quad_decimate "
        f"{result['quad_decimate']:g}, grey noise {result['noise_std']:g}"
    )
    print(f"  {'':22s} {'median':>8s} {'p99':>8s}   found   pos err med/p90     rot err med/p90")
    for name in ("marionette", "marionette_rgbd", "pupil_apriltags"):
        r = result[name]
        print(
            f"  {name:22s} {r['median_ms']:6.2f}ms {r['p99_ms']:6.2f}ms   "
            f"{r['tags_found']:3d}/{result['tags']}"
            f"   {r['median_position_error_mm']:5.2f}/{r['p90_position_error_mm']:5.2f} mm"
            f"   {r['median_rotation_error_deg']:5.2f}/{r['p90_rotation_error_deg']:5.2f} deg"
        )
    print(
        f"  ratio of medians marionette / pupil-apriltags: "
        f"{result['ratio_median_marionette_over_pupil']:.2f}   (target: median <= 5 ms)"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quad-decimate", type=float, nargs="+", default=[2.0, 1.0])
    parser.add_argument(
        "--noise",
        type=float,
        nargs="+",
        default=[0.0, 2.0],
        help="grey-level noise std of the frame sets",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench/perception_apriltag.json"))
    args = parser.parse_args(argv)
    K = CameraIntrinsics.from_fovy(640, 480, 45.0)
    results = []
    for noise in args.noise:
        frames = make_frames(args.frames, K, noise)
        for decimate in args.quad_decimate:
            result = run(frames, K, args.repeats, decimate, noise)
            results.append(result)
            _print(result)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
