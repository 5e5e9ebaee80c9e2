"""marionette.robots: Pinocchio models, reference postures, MuJoCo configuration layout,
objects."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots

ROOTS = {  # base kind: (root joint, its nq, its nv)
    "free_flyer": (pin.JointModelFreeFlyer().shortname(), 7, 6),
    "planar": (pin.JointModelPlanar().shortname(), 4, 3),
    "fixed": (None, 0, 0),
}


def urdf_joints(name: str) -> tuple[int, int, int]:
    """(nq, nv, mimics) of the URDF's movable joints, counted from its XML: a continuous joint
    is (cos, sin) in q; a joint with <mimic> is not in Pinocchio's model (fixed or mimic)."""
    nq = nv = mimics = 0
    for j in ET.parse(robots.robot(name).urdf).getroot().iter("joint"):
        if j.find("mimic") is not None:
            mimics += 1
        elif j.get("type") in ("revolute", "prismatic"):
            nq, nv = nq + 1, nv + 1
        elif j.get("type") == "continuous":
            nq, nv = nq + 2, nv + 1
    return nq, nv, mimics


@pytest.mark.parametrize("name", robots.robot_names())
def test_pinocchio_model_has_the_documented_base(name):
    model, geom = robots.load_pinocchio(name)
    root, base_nq, base_nv = ROOTS[robots.robot(name).base]
    nq, nv, _ = urdf_joints(name)
    assert (model.nq, model.nv) == (base_nq + nq, base_nv + nv)
    if root is None:
        assert model.names[1] != "root_joint"
    else:
        assert model.names[1] == "root_joint"
        assert model.joints[1].shortname() == root
    collisions = ET.parse(robots.robot(name).urdf).getroot().findall("link/collision")
    assert len(geom.geometryObjects) == len(collisions) > 0
    assert 0 < len(geom.collisionPairs) < len(geom.geometryObjects) ** 2 / 2


@pytest.mark.parametrize("name", robots.robot_names())
def test_reference_configuration_is_within_limits_and_collision_free(name):
    model, geom = robots.load_pinocchio(name)
    q = robots.reference_configuration(name, model)
    assert q.shape == (model.nq,)
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nq == 1:
            lo, hi = model.lowerPositionLimit[jm.idx_q], model.upperPositionLimit[jm.idx_q]
            assert lo <= q[jm.idx_q] <= hi, model.names[j]
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.computeCollisions(model, data, geom, gdata, q, False)
    hits = [
        (geom.geometryObjects[p.first].name, geom.geometryObjects[p.second].name)
        for p, r in zip(geom.collisionPairs, gdata.collisionResults)
        if r.isCollision()
    ]
    assert not hits


def test_talos_half_sitting_is_the_srdf_posture_with_grippers_just_open():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    q = robots.reference_configuration("talos", model)
    knee = model.joints[model.getJointId("leg_left_4_joint")].idx_q
    assert q[knee] == pytest.approx(0.859395)  # talos.srdf half_sitting
    assert q[2] == pytest.approx(1.01927)
    for g in robots.semantics("talos").grippers:
        i = model.joints[model.getJointId(g.joint)].idx_q
        # SRDF leaves them at 0 = the upper limit (open); the reference is strictly inside.
        assert model.upperPositionLimit[i] == 0.0
        assert q[i] == g.open_position < model.upperPositionLimit[i]
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    for sole in robots.robot("talos").sole_frames:
        X = data.oMf[model.getFrameId(sole)]
        assert abs(X.translation[2]) < 1e-5, "feet on the floor"
        # Flat up to talos.srdf's own ankle roll of -0.001708 rad.
        assert np.linalg.norm(pin.log3(X.rotation)) < 2e-3, "feet flat"


@pytest.mark.parametrize("name", robots.robot_names())
def test_mujoco_configuration_round_trip(name):
    model, _ = robots.load_pinocchio(name, with_collision=False)
    rng = np.random.default_rng(3)
    for _ in range(5):
        lo = np.maximum(model.lowerPositionLimit, -3)
        hi = np.minimum(model.upperPositionLimit, 3)
        q = pin.normalize(model, lo + rng.random(model.nq) * (hi - lo))
        qpos = robots.pinocchio_to_mujoco(name, q)
        # mimic fingers move in MuJoCo only
        mimics = urdf_joints(name)[2] if robots.robot(name).moving_mimics else 0
        assert qpos.size == model.nq - (1 if robots.robot(name).base == "planar" else 0) + mimics
        assert qpos.size == robots.mujoco_nq(name)
        assert np.allclose(robots.mujoco_to_pinocchio(name, qpos), q, atol=1e-12)
    if robots.robot(name).base == "free_flyer":
        q = robots.reference_configuration(name, model)
        assert np.allclose(robots.pinocchio_to_mujoco(name, q)[3:7], [q[6], q[3], q[4], q[5]])


@pytest.mark.parametrize("name", robots.object_names())
def test_objects_load_with_collision_geometry_and_their_mass(name):
    obj = robots.load_object(name)
    assert obj.model.names[1] == "root_joint" and obj.model.nq == 7
    urdf = ET.parse(robots.object_urdf(name)).getroot()
    assert len(obj.collision_model.geometryObjects) == len(urdf.findall("link/collision")) >= 1
    masses = [float(m.get("value")) for m in urdf.iter("mass")]
    assert pin.computeTotalMass(obj.model) == pytest.approx(sum(masses))
    assert obj.semantics.name == name
    fixed = robots.load_object(name, root="fixed")
    assert fixed.model.nq == 0


def test_unknown_names_list_the_known_ones():
    with pytest.raises(robots.UnknownModel, match=r"unknown robot 'pr2'; known robots: .*talos"):
        robots.robot("pr2")
    with pytest.raises(robots.UnknownModel, match=r"did you mean 'talos'"):
        robots.robot("tallos")
    with pytest.raises(robots.UnknownModel, match=r"unknown object 'chair'; known objects: \["):
        robots.load_object("chair")
    with pytest.raises(ValueError, match="root must be"):
        robots.load_object("plank", root="planar")
