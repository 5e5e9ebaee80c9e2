"""The demo scenes: a robot, objects placed around it, a floor, lights, cameras.

Each scene is written as one MJCF file (``models/scenes/<scene>.xml``, keyframe
``reference``: the robot in its reference posture, objects at rest) and a YAML file that
tells planners and perception where things start (``models/scenes/<scene>.yaml``): the
robot's base placement and every object's type, simulation kind and pose X_WO.

Moving things during a run: free objects (plank, ball, box, drill) are teleported by writing
their ``qpos`` (x y z qw qx qy qz) and zeroing their ``qvel``; fixtures (table, part,
pedestal, bar) are mocap bodies, moved with ``mocap_pos``/``mocap_quat``. Grasps are weld
equality constraints ``grasp/<gripper>/<object>``, inactive at start: activate one by setting
its ``eq_active`` and writing the current gripper-to-object pose into ``eq_data[3:10]``
(MuJoCo 2.2 weld data: anchor (3), relpose pos (3) + quat wxyz (4), torquescale).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from marionette.robots import robot

from .mjcf import assemble, object_part, placement, robot_part
from .objects import AircraftPart, Ball, Bar, Box, ObjectSpec, Pedestal, Plank, Table
from .robot_models import robot_semantics
from .semantics import Placement
from .xml_util import fmt, fmt_vec, homogeneous, indent_and_serialize, sub


@dataclass
class SceneObject:
    instance: str
    spec: ObjectSpec
    X_WO: np.ndarray


@dataclass
class SceneCamera:
    """A fixed camera of the scene, looking from ``eye`` at ``target``."""

    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    fovy: float = 45.0


@dataclass
class Scene:
    name: str
    description: str
    robot: str
    objects: list[SceneObject]
    X_WB: np.ndarray | None = None  # fixed-base robots: base placement
    cameras: list[SceneCamera] = field(default_factory=list)
    graspable: tuple[str, ...] = ()  # object instances the robot's grippers may weld


def scenes() -> list[Scene]:
    """Every scene, in a fixed order."""
    table, plank, part, ball, pedestal, bar, box = (
        Table(),
        Plank(),
        AircraftPart(),
        Ball(),
        Pedestal(),
        Bar(),
        Box(),
    )
    # Plank standing on its rear face (x up), tag faces (z) towards TALOS (-x of the world).
    R_plank = np.column_stack([[0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    # Table front edge 25 cm ahead of TALOS' base (clear of its knees), plank 21 cm behind it:
    # every handle is within reach of a gripper with the feet in place, and the tags are in the
    # head camera's view once TALOS looks down (tests/python/models/test_model_scenes.py).
    table_x = 0.60
    plank_X = homogeneous(
        R_plank, [table_x - table.depth / 2 + 0.21, 0.0, table.top_z() + plank.size[0] / 2]
    )
    out = [
        Scene(
            "talos_plank",
            "TALOS in half-sitting before a table with the plank standing on it "
            "(Nicolin 2022, sec. 3.4)",
            "talos",
            [SceneObject("table", table, placement(table_x)), SceneObject("plank", plank, plank_X)],
            graspable=("plank",),
        ),
        Scene(
            "talos_walk",
            "TALOS on a flat floor, a bar to step over 1 m ahead and a ball on a "
            "pedestal 2.2 m ahead (Dang 2012, ch. 5 and 6)",
            "talos",
            [
                SceneObject("bar", bar, placement(1.0)),
                SceneObject("pedestal", pedestal, placement(2.2)),
                SceneObject("ball", ball, placement(2.2, 0, pedestal.ball_rest_z(ball.radius))),
            ],
            graspable=("ball",),
        ),
        Scene(
            "tiago_deburr",
            "TIAGo with its deburring drill before the aircraft part (Nicolin 2022, sec. 5.3.3)",
            "tiago",
            # 10 cm into the floor (its stand's foot hidden): holes at 0.78-0.92 m, where the
            # head camera sees the held tool's side tags within 60 deg from every pre-grasp
            # of 20 seeded displacements; at 0.88-1.02 m the top row had none in 2 of 10
            [SceneObject("part", part, placement(0.95, 0.0, -0.10, np.pi))],
        ),
        Scene(
            "ur10_drill",
            "UR10 on its stand with the drilling spindle before the aircraft part "
            "(the drilling robot of Nicolin 2022, ch. 6)",
            "ur10",
            [SceneObject("part", part, placement(1.05, 0.0, 0.0, np.pi))],
            X_WB=np.eye(4),
            cameras=[SceneCamera("scene_rgbd", (0.40, -0.30, 1.35), (1.05, 0.0, 0.95))],
        ),
        Scene(
            "ur10_box",
            "UR10 on its stand, a table and a box to pick and place",
            "ur10",
            [
                SceneObject("table", table, placement(0.95)),
                SceneObject("box", box, placement(0.75, 0.25, table.top_z() + box.side / 2)),
            ],
            X_WB=np.eye(4),
            cameras=[SceneCamera("scene_rgbd", (0.2, -0.9, 1.6), (0.9, 0.0, 0.75))],
            graspable=("box",),
        ),
    ]
    return out


def scene_mjcf(scene: Scene, q_reference: np.ndarray) -> str:
    parts = [robot_part(scene.robot, q_reference, scene.X_WB)]
    for o in scene.objects:
        parts.append(object_part(o.spec, o.instance, o.X_WO))
    extra = [_camera(c) for c in scene.cameras]
    root = assemble(
        scene.name, parts, f"GENERATED by scripts/generate_models.py: {scene.description}.", extra
    )
    grippers = robot_semantics(scene.robot).grippers
    links = {g.name: g.link for g in grippers}
    if scene.graspable:
        eq = ET.Element("equality")
        for g in grippers:
            for inst in scene.graspable:
                sub(
                    eq,
                    "weld",
                    name=f"grasp/{g.name}/{inst}",
                    body1=links[g.name],
                    body2=inst,
                    active="false",
                )
        root.insert(list(root).index(root.find("worldbody")) + 1, eq)
    return indent_and_serialize(root)


def scene_object_pose(scene_mjcf: Path, name: str):
    """X_WO (pin.SE3) of object instance ``name`` as the scene's YAML (written by
    :func:`scene_yaml` beside the MJCF ``scene_mjcf``) places it; ValueError when it has none."""
    path = Path(scene_mjcf).with_suffix(".yaml")
    objects = {o["name"]: o for o in (yaml.safe_load(path.read_text()) or {}).get("objects", [])}
    if name not in objects:
        raise ValueError(f"{path}: no object {name!r} (objects: {sorted(objects)})")
    pose = objects[name]["pose"]
    return Placement(tuple(pose["xyz"]), tuple(pose["xyzw"])).se3()


def scene_yaml(scene: Scene) -> str:
    desc = robot(scene.robot)
    data = {
        "name": scene.name,
        "description": scene.description,
        "robot": scene.robot,
        "base": (
            Placement.from_matrix(scene.X_WB).to_dict()
            if scene.X_WB is not None
            else f"{desc.base} root joint, at the {desc.reference} configuration"
        ),
        "keyframe": "reference",
        "cameras": ([desc.camera] if desc.camera else []) + [c.name for c in scene.cameras],
        "objects": [
            {
                "name": o.instance,
                "object": o.spec.name,
                "sim": o.spec.sim,
                "pose": Placement.from_matrix(o.X_WO).to_dict(),
            }
            for o in scene.objects
        ],
        "grasp_welds": [
            f"grasp/{g.name}/{inst}"
            for g in robot_semantics(scene.robot).grippers
            for inst in scene.graspable
        ],
    }
    return (
        "# GENERATED by scripts/generate_models.py (python/marionette/models/scenes.py)\n"
        + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    )


def _camera(c: SceneCamera) -> ET.Element:
    """MuJoCo camera looking along its -z: x right, y up in the image."""
    eye, target = np.array(c.eye), np.array(c.target)
    back = eye - target
    back /= np.linalg.norm(back)  # camera +z
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    return ET.Element(
        "camera",
        name=c.name,
        mode="fixed",
        pos=fmt_vec(eye),
        xyaxes=fmt_vec([*right, *up]),
        fovy=fmt(c.fovy),
    )
