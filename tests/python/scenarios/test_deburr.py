"""Pieces of `marionette demo deburr` that need no running processes (thesis 000 §5.3.3): the
perturbed scene file (part and tool pose, MuJoCo keyframe included), the head's gaze, the
tool-axis criterion, and the constraint-graph plan with its TSP order."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.execution.tool_task import axis_offset
from marionette.scenarios.deburr import DeburrSettings, aim_head, draw_tool_offset, perturbed_scene
from marionette.scenarios.perturbations import place_mocap_body


def _pose(attrs: str) -> pin.SE3:
    pos = np.array(re.search(r'pos="([^"]+)"', attrs).group(1).split(), dtype=float)
    w, x, y, z = (float(v) for v in re.search(r'quat="([^"]+)"', attrs).group(1).split())
    return pin.SE3(pin.Quaternion(w, x, y, z).normalized().matrix(), pos)


def test_mocap_body_and_keyframe_both_moved():
    # MuJoCo resets mocap bodies to the keyframe's mpos/mquat: both must carry the new pose
    mjcf = (
        '<mujoco><worldbody><body name="a" pos="0 0 0" mocap="true"></body>'
        '<body name="part" pos="1 0 0" quat="1 0 0 0" mocap="true"></body></worldbody>'
        '<keyframe><key name="k" qpos="0" mpos="0 0 0 1 0 0" mquat="1 0 0 0 1 0 0 0" /></keyframe></mujoco>'
    )
    X = pin.SE3(pin.exp3(np.array([0.1, -0.2, 0.3])), np.array([0.9, 0.05, -0.02]))
    out = place_mocap_body(mjcf, "part", X)
    body = re.search(r'<body name="part"([^>]*)>', out).group(1)
    assert np.allclose(_pose(body).homogeneous, X.homogeneous, atol=1e-9)
    key = re.search(r"<key [^>]*/>", out).group(0)
    mpos = np.array(re.search(r'mpos="([^"]+)"', key).group(1).split(), dtype=float)
    mquat = np.array(re.search(r'mquat="([^"]+)"', key).group(1).split(), dtype=float)
    assert np.allclose(mpos[:3], 0) and np.allclose(mpos[3:], X.translation)
    q = pin.Quaternion(X.rotation)
    assert np.allclose(mquat[:4], [1, 0, 0, 0]) and np.allclose(mquat[4:], [q.w, q.x, q.y, q.z])
    with pytest.raises(Exception, match="no mocap body 'plank'"):
        place_mocap_body(mjcf, "plank", X)


def test_perturbed_scene_moves_the_part_and_the_tool_in_the_hand(tmp_path: Path):
    st = DeburrSettings()
    rng = np.random.default_rng(4)
    T = draw_tool_offset(rng, st)
    assert st.tool_offset_m / 2 <= np.linalg.norm(T.translation) <= st.tool_offset_m + 1e-12
    assert (
        np.radians(st.tool_offset_deg) / 2
        <= np.linalg.norm(pin.log3(T.rotation))
        <= np.radians(st.tool_offset_deg) + 1e-12
    )
    X = pin.SE3(pin.exp3(np.array([0, 0, 3.0])), np.array([0.97, 0.02, 0.01]))
    text = perturbed_scene(X, T, tmp_path / "scene.xml").read_text()
    assert np.allclose(
        _pose(re.search(r'<body name="part"([^>]*)>', text).group(1)).homogeneous, X.homogeneous
    )
    # nominal drill body: quat (0.7071, 0, 0.7071, 0) at the origin of its parent
    nominal = pin.SE3(
        pin.Quaternion(0.707106781188, 0, 0.707106781185, 0).normalized().matrix(), np.zeros(3)
    )
    drill = _pose(re.search(r'<body name="drill_link"([^>]*)>', text).group(1))
    assert np.allclose(drill.homogeneous, (nominal * T).homogeneous, atol=1e-9)
    assert 'meshdir="/' in text


def test_head_aims_the_optical_axis_at_the_target():
    model, _ = robots.load_pinocchio("tiago", with_collision=False)
    q = np.array(robots.reference_configuration("tiago"))
    frame = robots.robot("tiago").camera_frame
    for target in ([0.94, 0.0, 0.95], [0.9, 0.2, 1.1], [0.8, -0.15, 0.8]):
        qa = aim_head(model, q, frame, np.array(target))
        data = model.createData()
        pin.framesForwardKinematics(model, data, qa)
        p = data.oMf[model.getFrameId(frame)].actInv(np.array(target))
        assert np.hypot(p[0], p[1]) / p[2] < 1e-5  # on the optical axis, in front
        assert np.array_equal(
            np.delete(qa, [12, 13]), np.delete(q, [12, 13])
        )  # only the head moved


def test_axis_offset_closed_form():
    hole = pin.SE3(pin.exp3(np.array([0.0, np.pi, 0.0])), np.array([0.9, 0.1, 1.0]))  # axis -x
    a = hole.rotation[:, 0]
    tilt = pin.exp3(np.array([0.0, 0.0, np.radians(0.5)]))
    tool = pin.SE3(
        tilt @ hole.rotation, hole.translation - 0.005 * a + np.array([0.0, 0.0, 0.0007])
    )
    d, ang, standoff = axis_offset(tool, hole)
    assert ang == pytest.approx(0.5, abs=1e-9)
    # hole centre 0.7 mm above a line through the tool origin tilted by 0.5 deg in the horizontal plane
    assert d == pytest.approx(np.hypot(0.0007, 0.005 * np.sin(np.radians(0.5))), rel=1e-3)
    assert standoff == pytest.approx(0.005, abs=1e-9)


def test_deburr_problem_roots_tiago_fixed_and_keeps_its_reference_posture():
    """``root_joint: fixed`` drops TIAGo's planar base from the planning model; the ``home``
    reference is then taken joint by joint from the robot's own model."""
    from marionette.planning.problem import load_problem
    from marionette.scenarios.deburr import PROBLEM

    problem = load_problem(PROBLEM)
    model, _ = robots.load_pinocchio("tiago", with_collision=False)
    q_ref = np.array(robots.reference_configuration("tiago"))
    layout = problem.configuration_layout()
    assert not any("root_joint" in n for n in layout if n.startswith("tiago/"))
    for i, name in enumerate(layout):
        if name.startswith("tiago/"):
            j = model.joints[model.getJointId(name.split("/", 1)[1])]
            assert problem.q_init[i] == q_ref[j.idx_q], name
    assert len(problem.handles) == 15
