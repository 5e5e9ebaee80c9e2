"""Searching only around tracked tags, and the blur for noisy images: the same tags, the same
corners, less work.

References: the whole-image search (a region must reproduce it), the rendering's ground truth
(corner errors), the rendered noise's standard deviation (the noise estimate).
"""

from __future__ import annotations

import numpy as np
import pytest

from marionette import _visp
from marionette.perception import synthetic as syn
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig
from marionette.perception.tracking import TagRegionTracker, TrackingConfig, tag_box

K = CameraIntrinsics.from_fovy(640, 480, 45.0)
SIZE = 0.08


def _tags(rng, n):
    out = []
    for k in range(n):
        z = rng.uniform(0.6, 1.4)
        X = syn.look_at(
            [(k - 1) * 0.3 * z, rng.uniform(-0.12, 0.12) * z, z],
            tilt_deg=rng.uniform(0, 45),
            tilt_axis=(rng.normal(), rng.normal(), 0.0),
            roll_deg=rng.uniform(-180, 180),
        )
        out.append((20 + k, X))
    return out


def _render(tags, noise, rng):
    quads = [syn.tag_quad(t, SIZE, X) for t, X in tags]
    return syn.render(K, quads, background=120.0, noise_std=noise, rng=rng, supersample=3)


def _true_corners(X):
    corners = (X.homogeneous @ np.c_[_visp.tag_corners(SIZE), np.ones(4)].T).T[:, :3]
    return K.project(corners)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("noise", [0.0, 2.0])
def test_a_box_around_each_tag_reproduces_the_whole_image_search(seed, noise):
    rng = np.random.default_rng(seed)
    frame = _render(_tags(rng, 3), noise, rng)
    detector = AprilTagDetector(DetectorConfig(tag_sizes={20: SIZE, 21: SIZE, 22: SIZE}))
    whole = {d.tag_id: d for d in detector.detect(frame.gray, K)}
    assert whole
    boxes = [tag_box(d.corners, TrackingConfig()) for d in whole.values()]
    regional = {d.tag_id: d for d in detector.detect(frame.gray, K, regions=boxes)}
    assert regional.keys() == whole.keys()
    assert detector.last_stats.pixels_searched < 0.6 * K.width * K.height
    for tag_id, d in whole.items():
        np.testing.assert_allclose(regional[tag_id].corners, d.corners, atol=1e-4)
        np.testing.assert_allclose(regional[tag_id].X_CT.homogeneous, d.X_CT.homogeneous, atol=1e-4)


@pytest.mark.parametrize("noise", [0.0, 1.0, 2.0, 4.0])
def test_the_noise_estimate_reads_the_rendered_noise(noise):
    rng = np.random.default_rng(3)
    frame = _render(_tags(rng, 3), noise, rng)
    assert _visp.estimate_noise_sigma(frame.gray) == pytest.approx(noise, abs=0.05 + 0.05 * noise)


def test_the_blur_for_noise_keeps_corners_as_accurate_and_leaves_the_image_untouched():
    """Noisy images (2 grey levels) at full resolution, where AprilTag blurs in place: the
    caller's image must come back unchanged, every tag found unblurred must be found, and the
    corners must be as close to the truth as without the blur."""
    rng = np.random.default_rng(7)
    errors = {False: [], True: []}
    for _ in range(12):
        tags = _tags(rng, 3)
        frame = _render(tags, 2.0, rng)
        truth = {t: _true_corners(X) for t, X in tags}
        for adaptive in (False, True):
            config = DetectorConfig(
                tag_sizes=dict.fromkeys(truth, SIZE),
                quad_decimate=1.0,
                noise_adaptive_blur=adaptive,
            )
            detector = AprilTagDetector(config)
            gray = frame.gray.copy()
            found = {d.tag_id: d for d in detector.detect(gray, K)}
            np.testing.assert_array_equal(gray, frame.gray)
            assert detector.last_stats.quad_sigma == pytest.approx(0.8 if adaptive else 0.0)
            assert found.keys() == truth.keys()
            for t, d in found.items():
                errors[adaptive].append(np.linalg.norm(d.corners - truth[t], axis=1).mean())
    blurred, sharp = np.median(errors[True]), np.median(errors[False])
    assert blurred <= sharp + 0.01, (blurred, sharp)
    assert max(errors[True]) < 0.3


def test_the_tracker_searches_around_its_tags_and_the_whole_image_when_it_must():
    """A tag drifting 4 px per frame is followed in its box; one that jumps out of it is lost
    for one frame and found by the whole-image search that follows; a tag entering the view is
    found by the periodic whole-image search."""
    rng = np.random.default_rng(1)
    detector = AprilTagDetector(DetectorConfig(tag_sizes={20: SIZE, 21: SIZE}))
    tracker = TagRegionTracker(TrackingConfig(full_search_every=5))
    newcomer = syn.look_at([0.25, 0.05, 1.0], tilt_deg=15, roll_deg=-20)
    log = []
    for i in range(12):
        shift = 0.007 * i if i != 6 else 0.25  # ~4 px per frame; frame 6 jumps 150 px
        X = syn.look_at([-0.1 + shift, 0.0, 1.0], tilt_deg=20, roll_deg=10)
        tags = [(20, X)] + ([(21, newcomer)] if i >= 3 else [])
        frame = _render(tags, 0.0, rng)
        regions = tracker.regions()
        found = detector.detect(frame.gray, K, regions=regions)
        tracker.update(found, regions)
        log.append((regions is None, sorted(d.tag_id for d in found)))
    whole = [i for i, (w, _) in enumerate(log) if w]
    # 0: nothing tracked; 5: the 5th frame since; 7: after the jump lost the tag at 6; the
    # next periodic one is due at 12.
    assert whole == [0, 5, 7], log
    assert [ids for _, ids in log[:5]] == [[20]] * 5  # the newcomer (from frame 3) waits...
    assert log[5][1] == [20, 21]  # ...for the whole-image search
    assert log[6][1] == [21]  # the jumped tag is out of its box; the newcomer is tracked
    assert all(ids == [20, 21] for _, ids in log[7:]), log
    assert tracker.counts == {"full_searches": 3, "regional_searches": 9, "tracked_tags_lost": 1}


def test_a_tag_missing_for_a_few_frames_is_found_again_in_its_last_box():
    """Hidden for 3 frames (a hand passing, a glare): the whole-image search after the loss
    does not find it, and it comes back where it was, found in its kept box without waiting
    for the next whole-image search; after keep_lost_frames its box is dropped."""
    rng = np.random.default_rng(2)
    detector = AprilTagDetector(DetectorConfig(tag_sizes={20: SIZE, 21: SIZE}))
    tracker = TagRegionTracker(TrackingConfig(full_search_every=30, keep_lost_frames=5))
    X20 = syn.look_at([-0.15, 0.0, 1.0], tilt_deg=20, roll_deg=10)
    X21 = syn.look_at([0.2, 0.05, 1.0], tilt_deg=15, roll_deg=-20)
    log = []
    for i in range(14):
        hidden = 3 <= i < 6 or i >= 9
        frame = _render([(21, X21)] + ([] if hidden else [(20, X20)]), 0.0, rng)
        regions = tracker.regions()
        found = detector.detect(frame.gray, K, regions=regions)
        tracker.update(found, regions)
        log.append((regions, sorted(d.tag_id for d in found)))
    assert [r is None for r, _ in log[:8]] == [True, False, False, False, True, False, False, False]
    assert log[6][1] == [20, 21]  # back in its kept box, from a regional search
    assert len(log[8][0]) == 2  # both boxes searched
    # Hidden from frame 9 on: lost (full search at 10), its box kept until frame 9 + 5.
    assert log[10][0] is None
    assert len(log[13][0]) == 2  # last seen at frame 8: still searched at 13...
    regions = tracker.regions()
    assert regions is not None and len(regions) == 1  # ...and dropped after it
