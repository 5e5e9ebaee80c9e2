"""Seeded perturbations of a scenario trial: reproducible draws within their bounds, and an encoder
offset written as the MuJoCo joint's ``ref`` really shifts the reported angle (real MuJoCo)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.scenarios.perturbations import (
    PRESETS,
    PerturbationSettings,
    displaced,
    draw,
    scene_with_joint_offsets,
    slipped,
)

# the encoder offsets of ``--perturb all``: both arms, shoulder and wrist
BOTH_ARMS = {"arm_left_1_joint": 7.0, "arm_left_7_joint": 4.0}
BOTH_ARMS |= {"arm_right_1_joint": 7.0, "arm_right_7_joint": 4.0}


def test_draws_are_reproducible_and_within_bounds():
    assert draw(PRESETS["all"], 7) == draw(PRESETS["all"], 7)
    assert draw(PRESETS["all"], 7) != draw(PRESETS["all"], 8)
    for seed in range(200):
        p = draw(PRESETS["all"], seed)
        dx, dy, dyaw = p.displacement
        assert math.hypot(dx, dy) <= 0.05 + 1e-12 and abs(dyaw) <= math.radians(10.0) + 1e-12
        assert 0.005 - 1e-12 <= np.linalg.norm(p.slip[:3]) <= 0.01 + 1e-12
        assert math.radians(2.5) - 1e-12 <= np.linalg.norm(p.slip[3:]) <= math.radians(5.0) + 1e-12
        assert {k: abs(math.degrees(v)) for k, v in p.joint_offsets.items()} == pytest.approx(
            BOTH_ARMS
        )
    assert not draw(PerturbationSettings(), 3).any


def test_displacement_keeps_the_object_on_its_face_and_slip_is_in_its_frame():
    X = pin.SE3(pin.rpy.rpyToMatrix(0.0, math.pi / 2, 0.3), np.array([0.4, -0.02, 0.83]))
    Y = displaced(X, (0.03, -0.04, math.radians(8.0)))
    assert np.allclose(Y.translation - X.translation, [0.03, -0.04, 0.0])
    assert np.allclose(Y.rotation[2], X.rotation[2])  # world z of every body axis kept
    angle = pin.log3(Y.rotation @ X.rotation.T)
    assert np.allclose(angle, [0.0, 0.0, math.radians(8.0)])
    Z = slipped(X, (0.01, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert np.allclose(Z.translation, X.translation + X.rotation[:, 0] * 0.01)


def test_joint_offset_scene_reports_the_angle_plus_the_offset(tmp_path):
    from marionette._core import sim

    original = marionette.MODELS_DIR / "scenes" / "talos_plank.xml"
    offset = math.radians(7.0)
    path = scene_with_joint_offsets(original, {"arm_left_1_joint": offset}, tmp_path / "scene.xml")
    a, b = sim.MjScene(str(original)), sim.MjScene(str(path))
    a.reset_keyframe("reference")
    b.reset_keyframe("reference")
    # The joint is the robot's: qpos index from its name in the model's order (MJCF after the
    # free joint). Same reported qpos everywhere but that joint, reported offset higher: the
    # links of the offset scene sit where the original's sit at the reported angle minus offset.
    qa, qb = a.qpos.copy(), b.qpos.copy()
    from marionette import robots

    model, _ = robots.load_pinocchio("talos", with_collision=False)
    n = robots.mujoco_nq("talos")  # the robot's block of qpos (its moving fingers included)
    q = robots.mujoco_to_pinocchio("talos", qa[:n])
    i = model.joints[model.getJointId("arm_left_1_joint")].idx_q
    q[i] += offset
    qb[:n] = robots.pinocchio_to_mujoco("talos", q)
    b.qpos = qb
    b.forward()
    a.forward()
    assert np.allclose(
        a.body_pose("gripper_left_base_link"), b.body_pose("gripper_left_base_link"), atol=1e-9
    )
    # The physical stops stay at the same true angles: the joint's range and its position servo's
    # ctrlrange (reported units) move by the offset; the other joints' do not.
    import xml.etree.ElementTree as ET

    def ranges(scene):
        root = ET.parse(scene).getroot()
        joints = {j.get("name"): j.get("range") for j in root.iter("joint")}
        servos = {a.get("joint"): a.get("ctrlrange") for a in root.iter("general")}
        return joints, servos

    (ja, sa), (jb, sb) = ranges(original), ranges(path)
    for table_a, table_b in ((ja, jb), (sa, sb)):
        lo_a, hi_a = map(float, table_a["arm_left_1_joint"].split())
        lo_b, hi_b = map(float, table_b["arm_left_1_joint"].split())
        assert (lo_b - lo_a, hi_b - hi_a) == pytest.approx((offset, offset), abs=1e-8)
        assert table_a["arm_right_1_joint"] == table_b["arm_right_1_joint"]
    with pytest.raises(ValueError, match="no joint 'nope'"):
        scene_with_joint_offsets(original, {"nope": 0.1}, tmp_path / "bad.xml")


def test_all_is_every_part_at_once_with_the_magnitudes_plank_flip_is_judged_under():
    """``--perturb all`` (plank-flip's trial set): 5 cm / 10° displacement, in the hand a 1 cm /
    5° slip (welded grasps) or a 2.5-5 N push (friction grasps), 7° / 4° on both of TALOS'
    shoulders and wrists, 2 mm / 0.5° camera noise; each part sets a subset of it."""
    from marionette.scenarios.perturbations import PARTS, PRESETS, PerturbationSettings

    assert PRESETS["all"] == PerturbationSettings(
        displacement_m=0.05,
        displacement_deg=10.0,
        slip_m=0.01,
        slip_deg=5.0,
        push_n=5.0,
        push_s=0.1,
        joint_offsets_deg=BOTH_ARMS,
        camera_noise_m=0.002,
        camera_noise_deg=0.5,
    )
    # push alone, slippery: for friction grasps only, named on their own
    assert set(PRESETS) == {"all", "push", "slippery", *PARTS}
    full = PRESETS["all"]
    for name, settings in PRESETS.items():
        for field_name in (
            "displacement_m",
            "displacement_deg",
            "slip_m",
            "slip_deg",
            "camera_noise_m",
            "camera_noise_deg",
        ):
            assert getattr(settings, field_name) in (0.0, getattr(full, field_name)), (
                name,
                field_name,
            )
        assert set(settings.joint_offsets_deg) <= set(full.joint_offsets_deg)


def test_a_push_is_drawn_after_the_other_draws_within_its_bounds():
    """The push preset: 1/2 to 1 of push_n in a direction spread over the sphere, a delay in
    [0, 1] s; drawn after the others, so that a seed's displacement, slip and offsets are those
    it drew before pushes existed."""
    with_push = PerturbationSettings(**{**PRESETS["all"].__dict__, "push_n": 6.0, "push_s": 0.2})
    without = PerturbationSettings(**{**PRESETS["all"].__dict__, "push_n": 0.0})
    directions = []
    for seed in range(300):
        p, q = draw(with_push, seed), draw(without, seed)
        assert (p.displacement, p.slip, p.joint_offsets) == (
            q.displacement,
            q.slip,
            q.joint_offsets,
        )
        f = np.array(p.push)
        assert 3.0 - 1e-9 <= np.linalg.norm(f) <= 6.0 + 1e-9
        assert 0.0 <= p.push_delay_s <= 1.0 and p.push_s == 0.2
        directions.append(f / np.linalg.norm(f))
        assert q.push == (0.0, 0.0, 0.0) and q.push_s == 0.0
    # Directions spread over the sphere: their mean is near 0 (1/sqrt(300) per axis).
    assert np.linalg.norm(np.mean(directions, axis=0)) < 0.15
    assert PRESETS["push"].push_n == 5.0 == PRESETS["all"].push_n


def test_a_push_is_refused_where_grasps_are_welds_and_a_slip_where_they_hold_by_friction():
    from marionette.scenarios import SCENARIOS
    from marionette.scenarios.base import RunOptions, ScenarioError

    push = draw(PRESETS["push"], 1)
    with pytest.raises(ScenarioError, match="push on the held object"):
        SCENARIOS["plank-flip"].check_options(RunOptions(perturbation=push))
    SCENARIOS["ur10-box"].check_options(RunOptions(perturbation=push))
    slip = draw(PerturbationSettings(slip_m=0.01, slip_deg=5.0), 1)
    with pytest.raises(ScenarioError, match="holds its objects by friction"):
        SCENARIOS["ur10-box"].check_options(RunOptions(perturbation=slip))
    # Without the admittance ur10-box welds: the slip applies, the push is refused.
    welded = RunOptions(perturbation=slip, gripper_admittance=False)
    SCENARIOS["ur10-box"].check_options(welded)
    with pytest.raises(ScenarioError, match="push on the held object"):
        SCENARIOS["ur10-box"].check_options(RunOptions(perturbation=push, gripper_admittance=False))
    # A friction change, like a push, needs a grasp that friction holds.
    oily = draw(PRESETS["slippery"], 1)
    assert oily.any and oily.carry_friction == 0.25
    SCENARIOS["ur10-box"].check_options(RunOptions(perturbation=oily))
    for scenario, options in (
        ("plank-flip", RunOptions(perturbation=oily)),
        ("ur10-box", RunOptions(perturbation=oily, gripper_admittance=False)),
    ):
        with pytest.raises(ScenarioError, match="friction change on the held object"):
            SCENARIOS[scenario].check_options(options)


def test_the_in_hand_part_acts_on_either_kind_of_grasp_through_what_it_can_feel():
    """``in-hand`` (and so ``all``) holds a slip and a push: a welded grasp takes the slip (the
    weld is moved), a friction grasp the push (a weld would not feel it, a slip would move a
    weld it does not have); the other is dropped with a note, and check_options accepts both."""
    from marionette.scenarios import SCENARIOS
    from marionette.scenarios.base import RunOptions
    from marionette.scenarios.perturbations import acting_on

    p = draw(PRESETS["all"], 3)
    assert any(p.slip) and any(p.push)
    by_friction, note = acting_on(p, friction_grasps=True)
    assert not any(by_friction.slip) and by_friction.push == p.push and "slip" in note
    assert by_friction.displacement == p.displacement
    assert by_friction.joint_offsets == p.joint_offsets
    welded, note = acting_on(p, friction_grasps=False)
    assert welded.slip == p.slip and not any(welded.push) and "push" in note
    assert acting_on(draw(PRESETS["displacement"], 3), True)[1] is None
    in_hand = draw(PRESETS["in-hand"], 3)  # the UR10 has no TALOS joints to offset
    for scenario, options in (
        ("plank-flip", RunOptions(perturbation=p)),
        ("plank-flip", RunOptions(perturbation=p, gripper_admittance=True)),
        ("ur10-box", RunOptions(perturbation=in_hand)),
        ("ur10-box", RunOptions(perturbation=in_hand, gripper_admittance=False)),
    ):
        SCENARIOS[scenario].check_options(options)


def test_the_slip_comes_at_the_last_carry_whatever_the_plans_steps():
    """The hand-over plans of three plank-flip seeds put the carry to the placement at steps 12,
    9 and 9: the slip lands there (its first motion step after the hand-over), not at a fixed
    index; a plan that never holds the object has no carry."""
    from types import SimpleNamespace

    from marionette.scenarios.plan_and_execute import last_carry_step

    R, L = "talos/right_gripper", "talos/left_gripper"

    def plan(layout):
        return [
            SimpleNamespace(kind=kind, grasps={g: f"plank/{h}" for g, h in grasps.items()})
            for kind, grasps in layout
        ]

    free, right, left, both = {}, {R: "H1"}, {L: "H4"}, {R: "H1", L: "H4"}
    seed4 = [("motion", free)] * 3 + [("motion", right)] * 7 + [("grasp", right)]
    seed4 += [("release", left), ("motion", left), ("motion", left), ("motion", left)]
    seed4 += [("release", free), ("motion", free), ("motion", free)]
    seed101 = [("motion", free), ("motion", free), ("grasp", free), ("motion", right)]
    seed101 += [("motion", right)] * 3 + [("grasp", right), ("release", left), ("motion", left)]
    seed101 += [("motion", left), ("release", free), ("motion", free), ("motion", free)]
    assert last_carry_step(plan(seed4), "plank") == 12
    assert last_carry_step(plan(seed101), "plank") == 9
    # One hand only (ur10-box): the carry after the grasp.
    pick = [("motion", free), ("grasp", free), ("motion", right), ("motion", right)]
    pick += [("release", free), ("motion", free)]
    assert last_carry_step(plan(pick), "plank") == 2
    assert last_carry_step(plan([("motion", both)]), "box") is None
