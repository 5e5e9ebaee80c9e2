"""The YAML declarations of models/: they parse, name real links, and mean what they say
(handles approached from outside the object, tags printed on a face, contact polygons flat,
convex and facing out)."""

from __future__ import annotations

from pathlib import Path

import coal
import numpy as np
import pinocchio as pin
import pytest

from marionette import MODELS_DIR, robots
from marionette.models.semantics import (
    Placement,
    SemanticsError,
    load_semantics,
    pregrasp_distance,
    semantics_from_dict,
)

OBJECTS = robots.object_names()


def _signed_distance(geom: pin.GeometryModel, gdata_placements, point: np.ndarray) -> float:
    """Distance [m] from ``point`` (world) to the nearest collision geometry; < 0 inside."""
    probe = coal.Sphere(1e-6)
    M_probe = coal.Transform3s(np.eye(3), point)
    best = np.inf
    for go, M in zip(geom.geometryObjects, gdata_placements):
        req, res = coal.DistanceRequest(), coal.DistanceResult()
        req.enable_signed_distance = True
        d = coal.distance(
            go.geometry, coal.Transform3s(M.rotation, M.translation), probe, M_probe, req, res
        )
        best = min(best, d)
    return best


def _object_placements(obj):
    data = obj.model.createData()
    gdata = pin.GeometryData(obj.collision_model)
    pin.updateGeometryPlacements(
        obj.model, data, obj.collision_model, gdata, pin.neutral(obj.model)
    )
    return [gdata.oMg[i] for i in range(len(obj.collision_model.geometryObjects))]


def _link_placement(model, link: str) -> pin.SE3:
    data = model.createData()
    q = pin.neutral(model)
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[model.getFrameId(link)]


def test_every_yaml_parses():
    files = sorted((MODELS_DIR / "objects").glob("*.yaml"))
    assert len(files) == len(OBJECTS)
    for path in files:
        assert load_semantics(path).name == Path(path).stem
    for name in robots.robot_names():
        assert robots.semantics(name).name == name


@pytest.mark.parametrize("name", robots.robot_names())
def test_robot_declarations_name_links_of_the_urdf(name):
    model, _ = robots.load_pinocchio(name, with_collision=False)
    sem = robots.semantics(name)
    assert sem.grippers, f"{name} declares no gripper"
    for link in sem.links():
        assert model.existBodyName(link), (
            f"{name}: {link} is not a link of {robots.robot(name).urdf}"
        )
    for g in sem.grippers:
        assert g.name.startswith(f"{name}/")
        if g.joint is not None:
            j = model.joints[model.getJointId(g.joint)]
            lo, hi = model.lowerPositionLimit[j.idx_q], model.upperPositionLimit[j.idx_q]
            assert lo < g.open_position < hi and lo < g.closed_position < hi


@pytest.mark.parametrize("name", OBJECTS)
def test_object_declarations_name_links_of_the_urdf(name):
    obj = robots.load_object(name)
    for link in obj.semantics.links():
        assert obj.model.existBodyName(link)
    for item in [*obj.semantics.handles, *obj.semantics.grippers, *obj.semantics.contacts]:
        assert item.name.startswith(f"{name}/"), item.name


@pytest.mark.parametrize("name", [o for o in OBJECTS if robots.load_object(o).semantics.handles])
def test_pregrasp_is_outside_the_object_and_grasp_on_or_in_it(name):
    """Approaching along the handle's x axis, the gripper comes from free space (HPP pre-grasp
    at clearance) and ends on the object (at most 1 mm off its surface)."""
    obj = robots.load_object(name)
    placements = _object_placements(obj)
    for h in obj.semantics.handles:
        X_WH = _link_placement(obj.model, h.link) * h.pose.se3()
        approach = X_WH.rotation @ np.asarray(h.approach)
        pregrasp = X_WH.translation - h.clearance * approach
        assert _signed_distance(obj.collision_model, placements, pregrasp) > 0.005, h.name
        assert _signed_distance(obj.collision_model, placements, X_WH.translation) < 1e-3, h.name


@pytest.mark.parametrize("name", [o for o in OBJECTS if robots.load_object(o).semantics.tags])
def test_tags_lie_on_a_face_and_face_out(name):
    """A tag frame's origin is on the surface (its printed face 0.1 mm proud), free space in
    front of it (+z), material behind it (-z)."""
    obj = robots.load_object(name)
    placements = _object_placements(obj)
    for t in obj.semantics.tags:
        X = _link_placement(obj.model, t.link) * t.pose.se3()
        z = X.rotation[:, 2]
        d0 = _signed_distance(obj.collision_model, placements, X.translation)
        assert 0.0 <= d0 < 2e-4, f"tag {t.id}: {d0}"
        assert _signed_distance(obj.collision_model, placements, X.translation + 0.01 * z) > 0.009
        assert _signed_distance(obj.collision_model, placements, X.translation - 0.002 * z) < 0


def test_tiago_drill_tags_lie_on_the_tool_and_one_faces_every_side():
    """TIAGo's drill is servoed on its own tags (deburr): each lies on the tool's surface and
    faces out, and wherever the camera stands around the tool axis, tags of both rings face it
    within 45 deg (a ring of four, 8 cm apart along the housing)."""
    model, collision = robots.load_pinocchio("tiago", with_collision=True)
    data, gdata = model.createData(), pin.GeometryData(collision)
    pin.updateGeometryPlacements(model, data, collision, gdata, pin.neutral(model))
    drill = [
        i
        for i, g in enumerate(collision.geometryObjects)
        if model.frames[g.parentFrame].name == "drill_link"
    ]
    assert drill, "no collision geometry on drill_link"
    tool = pin.GeometryModel()
    for i in drill:
        tool.addGeometryObject(collision.geometryObjects[i])
    placements = [gdata.oMg[i] for i in drill]
    X_WL = _link_placement(model, "drill_link")
    tags = [t for t in robots.semantics("tiago").tags if t.link == "drill_link"]
    assert len(tags) == 8
    for t in tags:
        X = X_WL * t.pose.se3()
        z = X.rotation[:, 2]
        assert 0.0 <= _signed_distance(tool, placements, X.translation) < 2e-4, f"tag {t.id}"
        assert _signed_distance(tool, placements, X.translation + 0.01 * z) > 0.009, f"tag {t.id}"
        assert _signed_distance(tool, placements, X.translation - 0.002 * z) < 0, f"tag {t.id}"
    normals = np.array([t.pose.se3().rotation[:, 2] for t in tags])  # in the tool frame
    heights = np.array([t.pose.xyz[2] for t in tags])
    assert np.allclose(normals[:, 2], 0.0) and np.ptp(heights) >= 0.08
    for azimuth in np.radians(np.arange(0.0, 360.0, 5.0)):
        view = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
        facing = np.degrees(np.arccos(np.clip(normals @ view, -1, 1))) <= 45.0 + 1e-9
        assert {h for h, f in zip(heights, facing) if f} == set(heights), np.degrees(azimuth)


def test_tag_ids_are_unique_across_all_models():
    ids = [t.id for o in OBJECTS for t in robots.load_object(o).semantics.tags]
    ids += [
        t.id for n in robots.robot_names() for t in robots.semantics(n).tags if n != "tiago"
    ]  # TIAGo's mounted drill reuses the drill's tag ids from 30
    assert len(ids) == len(set(ids)), sorted(ids)


@pytest.mark.parametrize("name", OBJECTS)
def test_contact_polygons_are_flat_convex_and_face_out_of_the_object(name):
    obj = robots.load_object(name)
    com = obj.model.inertias[1].lever
    for c in obj.semantics.contacts:
        p, n = c.points, c.normal()
        assert np.allclose((p - p[0]) @ n, 0.0, atol=1e-12), f"{c.name} not planar"
        k = len(p)
        turns = [
            np.cross(p[(i + 1) % k] - p[i], p[(i + 2) % k] - p[(i + 1) % k]) @ n for i in range(k)
        ]
        assert min(turns) > 0, f"{c.name} not convex counter-clockwise"
        assert (p.mean(axis=0) - com) @ n > 0, f"{c.name} faces into the object"


def test_talos_soles_face_down_under_the_sole_frames():
    for c in robots.semantics("talos").contacts:
        assert np.allclose(c.normal(), [0, 0, -1])
        assert np.allclose(c.points[:, 2], 0.0)
        assert np.allclose(np.ptp(c.points, axis=0)[:2], [0.205, 0.122])


def test_pregrasp_distance_adds_both_clearances():
    g = robots.semantics("talos").gripper("talos/left_gripper")
    h = robots.load_object("plank").semantics.handle("plank/H1")
    assert pregrasp_distance(g, h) == pytest.approx(g.clearance + h.clearance)


def test_placement_matrix_matches_pinocchio():
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        p = Placement(tuple(rng.normal(size=3)), tuple(q))
        assert np.allclose(p.matrix(), p.se3().homogeneous, atol=1e-12)
        assert np.allclose(Placement.from_matrix(p.matrix()).matrix(), p.matrix(), atol=1e-12)


GOOD = {
    "name": "thing",
    "handles": [
        {
            "name": "thing/h",
            "link": "base_link",
            "clearance": 0.05,
            "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
        }
    ],
}


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d["handles"][0].pop("link"), r"handles\[0\]: missing keys \['link'\]"),
        (
            lambda d: d["handles"][0]["pose"].update(xyzw=[0, 0, 0, 2]),
            r"handles\[0\].pose: .*norm 2",
        ),
        (lambda d: d["handles"][0].update(clearance=-1), r"clearance must be a finite number >= 0"),
        (lambda d: d["handles"][0].update(mask=[1, 1, 1]), r"mask must be six 0/1 values"),
        (lambda d: d["handles"].append(dict(d["handles"][0])), r"duplicate handle names"),
        (lambda d: d.update(grasps=[]), r"unknown top-level keys \['grasps'\]"),
        (
            lambda d: d.update(
                tags=[
                    {
                        "id": -3,
                        "family": "tag36h11",
                        "size": 0.05,
                        "link": "l",
                        "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
                    }
                ]
            ),
            r"tags\[0\]: id must be a non-negative integer",
        ),
        (
            lambda d: d.update(
                grippers=[
                    {
                        "name": "g",
                        "link": "l",
                        "clearance": 0.1,
                        "joint": "j",
                        "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
                    }
                ]
            ),
            r"grippers\[0\]: a gripper joint needs open_position and closed_position",
        ),
        (
            lambda d: d.update(
                grippers=[
                    {
                        "name": "g",
                        "link": "l",
                        "clearance": 0.1,
                        "joint": "j",
                        "open_position": 0,
                        "closed_position": 0.04,
                        "admittance": {"lever_arm": 1.0, "stiffness": 3.0},
                        "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
                    }
                ]
            ),
            r"grippers\[0\]: admittance must map parameters among "
            r"\['acceleration'.*got .*stiffness",
        ),
        (
            lambda d: d.update(
                grippers=[
                    {
                        "name": "g",
                        "link": "l",
                        "clearance": 0.1,
                        "admittance": {"lever_arm": 1.0},
                        "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
                    }
                ]
            ),
            r"grippers\[0\]: admittance parameters need a gripper joint",
        ),
        (
            lambda d: d.update(
                grippers=[
                    {
                        "name": "g",
                        "link": "l",
                        "clearance": 0.1,
                        "joint": "j",
                        "open_position": 0,
                        "closed_position": 0.04,
                        "admittance": {"speed": float("nan")},
                        "pose": {"xyz": [0, 0, 0], "xyzw": [0, 0, 0, 1]},
                    }
                ]
            ),
            r"grippers\[0\]: admittance: speed must be a finite number",
        ),
    ],
)
def test_bad_declarations_raise_precise_errors(mutate, message):
    import copy

    data = copy.deepcopy(GOOD)
    semantics_from_dict(copy.deepcopy(data), "thing.yaml")  # the unmutated one is fine
    mutate(data)
    with pytest.raises(SemanticsError, match=message):
        semantics_from_dict(data, "thing.yaml")


def test_missing_and_malformed_files_are_named(tmp_path):
    with pytest.raises(SemanticsError, match="no such file"):
        load_semantics(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(SemanticsError, match=rf"{bad}:2: not valid YAML") as e:
        load_semantics(bad)  # the line where the parser stopped
    assert "\n" not in str(e.value)
