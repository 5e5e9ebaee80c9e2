"""What the browser viewer draws, from the run's LCM messages, into a meshcat scene.

:class:`ViewerScene` turns one message at a time into meshcat commands: the robot's visual meshes
(its URDF's collision meshes through Pinocchio's MeshcatVisualizer) posed from ROBOT_STATE, the
scene's objects (their
URDF) posed from SIM_OBJECT_POSES / OBJECT_POSES, triads at the grippers and handles, the
FOOTSTEP_PLAN's soles, and a text panel with the supervisor's state (SUPERVISOR_STATE). It does no
I/O of its own: the viewer process (:mod:`.node`) and the log replay (:mod:`.replay`) feed it.

meshcat paths: ``robot/...``, ``objects/<name>/...``, ``frames/<gripper|handle>``,
``footsteps/<i>``, ``fsm``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from marionette import robots
from marionette.control.client import configuration_from_state

SOLE_HEIGHT = 0.01  # [m] of the sole box drawn for a footstep
LEFT_RGB, RIGHT_RGB = 0x2060E0, 0xE06020


class ViewerError(ValueError):
    """The viewer cannot draw what it was asked to (unknown robot, bad scene file)."""


def scene_objects(scene: Path | None) -> dict[str, tuple[str, np.ndarray]]:
    """Object instance name -> (object model name, initial X_WO 4 x 4) from a scene's YAML
    (``models/scenes/<s>.yaml`` next to the MJCF ``scene``), or {} without one."""
    if scene is None:
        return {}
    path = Path(scene).with_suffix(".yaml")
    if not path.is_file():
        return {}
    try:
        doc = yaml.safe_load(path.read_text()) or {}
        out = {}
        for o in doc.get("objects", []):
            x, y, z, w = o["pose"]["xyzw"]
            out[o["name"]] = (o["object"], _X(o["pose"]["xyz"], (w, x, y, z)))
        return out
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as e:
        raise ViewerError(f"{path}: cannot read the scene's objects: {e}") from None


def _X(position, quaternion_wxyz) -> np.ndarray:
    w, x, y, z = quaternion_wxyz
    return pin.SE3(
        pin.Quaternion(w, x, y, z).normalized().matrix(), np.asarray(position, float)
    ).homogeneous


def default_view(model: pin.Model, data: pin.Data, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(target, eye) [m] of a camera that frames the robot at ``q``: aimed at the middle of its
    joints, from the front-right and above, as far as its size asks."""
    pin.forwardKinematics(model, data, q)
    points = np.array([data.oMi[j].translation for j in range(model.njoints)])
    lo, hi = points.min(axis=0), points.max(axis=0)
    target = 0.5 * (lo + hi)
    size = max(float(np.linalg.norm(hi - lo)), 0.5)
    eye = target + size * np.array([1.6, -1.4, 0.7])
    return target, eye


class ViewerScene:
    """Draws the run of ``robot`` (with the objects of ``scene``) into meshcat visualizer
    ``vis``."""

    def __init__(self, vis: Any, robot: str, scene: Path | None = None) -> None:
        from pinocchio.visualize import MeshcatVisualizer

        try:
            desc = robots.robot(robot)
        except robots.UnknownModel as e:
            raise ViewerError(e.args[0]) from None
        self.vis = vis
        self.robot = robot
        self.robot_name = desc.name
        self.model, _ = robots.load_pinocchio(robot, with_collision=False)
        self.data = self.model.createData()
        # The collision meshes (STL, the ones our MJCF models use): the visual Collada meshes
        # (9 MB for an arm) stall the page's loader in a headless browser without a GPU.
        visual = pin.buildGeomFromUrdf(
            self.model,
            str(desc.urdf),
            pin.GeometryType.COLLISION,
            package_dirs=robots.package_dirs(),
        )
        self._robot_viz = MeshcatVisualizer(self.model, visual, visual)
        self._robot_viz.initViewer(viewer=vis)
        self._robot_viz.loadViewerModel(rootNodeName="robot")
        vis["robot"].set_property("visible", False)  # until the first ROBOT_STATE
        self.grippers = robots.semantics(robot).grippers
        initial = scene_objects(scene)
        self.object_models = {n: kind for n, (kind, _) in initial.items()}
        self._objects: dict[str, Any] = {}  # name -> (handles) once loaded
        for name, (_, X_WO) in initial.items():  # static objects (a mocap table) never move
            if self._object(name) is not None:
                self.vis[f"objects/{name}"].set_transform(X_WO)
        self.robot_states = 0
        self.fsm_text = ""
        self.footsteps = 0
        length, width = desc.feet[0].size if desc.feet else (0.2, 0.12)
        self.sole = (length, width, SOLE_HEIGHT)
        q_reference = robots.reference_configuration(robot, self.model)
        self.view_target, eye = default_view(self.model, self.data, q_reference)
        self.set_camera(self.view_target, eye)
        self._draw_fsm("waiting for the supervisor")

    # ---- camera ---------------------------------------------------------------------------------
    def set_camera(self, target, eye) -> None:
        """Orbit camera looking at ``target`` from ``eye`` (world [m])."""
        self.vis["/Cameras/default"].set_transform(
            pin.SE3(np.eye(3), np.asarray(target, float)).homogeneous
        )
        # meshcat's camera node is y-up ("rotated"): world (x, y, z) offset = rotated (x, z, -y).
        d = np.asarray(eye, float) - np.asarray(target, float)
        self.vis["/Cameras/default/rotated/<object>"].set_property("position", [d[0], d[2], -d[1]])

    # ---- messages -------------------------------------------------------------------------------
    def on_robot_state(self, msg: Any) -> None:
        """ROBOT_STATE: the robot's meshes and its gripper frames."""
        q = configuration_from_state(self.model, msg)
        self._robot_viz.display(q)
        if self.robot_states == 0:
            self.vis["robot"].set_property("visible", True)
        self.robot_states += 1
        pin.framesForwardKinematics(self.model, self.data, q)
        for g in self.grippers:
            if not self.model.existFrame(g.link):
                continue
            X_WL = self.data.oMf[self.model.getFrameId(g.link)]
            self._triad(f"frames/{g.name}", (X_WL * g.pose.se3()).homogeneous)

    def on_object_poses(self, msg: Any) -> None:
        """SIM_OBJECT_POSES or OBJECT_POSES: every object's mesh and handle frames, world pose."""
        for o in msg.objects:
            handles = self._object(o.object_name)
            if handles is None:
                continue
            X_WO = _X(o.position_world, o.quaternion_world)
            self.vis[f"objects/{o.object_name}"].set_transform(X_WO)
            for h in handles:
                self._triad(f"frames/{h.name}", X_WO @ h.pose.se3().homogeneous)

    def on_footstep_plan(self, msg: Any) -> None:
        """FOOTSTEP_PLAN: one sole box per planned step (left blue, right orange)."""
        import meshcat.geometry as g

        self.vis["footsteps"].delete()
        for s in msg.steps:
            node = self.vis[f"footsteps/{s.index}"]
            node.set_object(
                g.Box(self.sole),
                g.MeshLambertMaterial(
                    color=LEFT_RGB if s.is_left else RIGHT_RGB, opacity=0.6, transparent=True
                ),
            )
            R = pin.rpy.rpyToMatrix(0.0, 0.0, s.yaw)
            node.set_transform(pin.SE3(R, np.array([s.x, s.y, s.z + self.sole[2] / 2])).homogeneous)
        self.footsteps = len(msg.steps)

    def on_supervisor_state(self, msg: Any) -> None:
        """SUPERVISOR_STATE: the FSM state, step and status as a text panel."""
        step = f"step {msg.step_index + 1}/{msg.num_steps}" if msg.step_index >= 0 else ""
        text = f"{msg.plan_name}  {step}\n{msg.state}\n{msg.status}"
        if text != self.fsm_text:
            self._draw_fsm(text)

    # ---- drawing --------------------------------------------------------------------------------
    def _object(self, name: str):
        """Loads object ``name``'s meshes under objects/<name> once; returns its handles
        (None for an object without a model)."""
        if name in self._objects:
            return self._objects[name]
        from pinocchio.visualize import MeshcatVisualizer

        kind = self.object_models.get(name, name)
        if kind not in robots.object_names():
            self._objects[name] = None  # e.g. a perception-only name: nothing to draw
            return None
        obj = robots.load_object(kind, root="fixed")
        viz = MeshcatVisualizer(obj.model, obj.collision_model, obj.collision_model)
        viz.initViewer(viewer=self.vis)
        viz.loadViewerModel(rootNodeName=f"objects/{name}")
        viz.display(pin.neutral(obj.model))
        self._objects[name] = list(obj.semantics.handles)
        return self._objects[name]

    def _triad(self, path: str, X: np.ndarray, scale: float = 0.1) -> None:
        import meshcat.geometry as g

        node = self.vis[path]
        if path not in getattr(self, "_drawn", set()):
            node.set_object(g.triad(scale))
            self._drawn = getattr(self, "_drawn", set()) | {path}
        node.set_transform(X)

    def _draw_fsm(self, text: str) -> None:
        """The FSM text on a panel above the scene, one line per text layer. meshcat has no 2D
        overlay; its "_text" texture is drawn on a canvas when the page builds the scene (an
        image texture decodes asynchronously and meshcat renders only on change: a page loaded
        after the last command could show an empty panel)."""
        import meshcat.geometry as g

        self.fsm_text = text
        target = self.view_target
        # In the x-z plane behind the robot, facing the default eye (which looks from -y).
        centre = np.array([target[0], target[1] + 0.8, target[2] + 1.2])
        panel = self.vis["fsm/panel"]
        panel.set_object(g.Box([1.3, 0.001, 0.34]), g.MeshBasicMaterial(color=0xF0F0F0))
        panel.set_transform(pin.SE3(np.eye(3), centre).homogeneous)
        self.vis["fsm/lines"].delete()
        for i, line in enumerate(text.splitlines()[:3]):
            texture = g.GenericTexture(
                {"type": "_text", "text": line or " ", "font_size": 36, "font_face": "sans-serif"}
            )
            node = self.vis[f"fsm/lines/{i}"]
            # The 256 x 256 canvas holds the line in its middle band: a 1.2 x 0.4 m face puts
            # lines 0.1 m apart; just in front of the panel (towards -y).
            # Front faces only (meshcat draws both by default): the box's +y face would show the
            # canvas upside down through the transparent -y face. The layers overlap: their
            # transparent texels must not hide the lines behind them in the depth buffer.
            node.set_object(
                g.Box([1.2, 0.001, 0.4]),
                g.MeshBasicMaterial(
                    map=texture, transparent=True, side=0, alphaTest=0.1, depthWrite=False
                ),
            )
            node.set_transform(pin.SE3(np.eye(3), centre + [0.0, -0.01, 0.1 - 0.1 * i]).homogeneous)
