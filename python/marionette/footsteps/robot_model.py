"""The robot seen by the footstep optimiser: Pinocchio model, sole / hand / camera frames, feet.

Only the pieces the augmented robot needs: a Pinocchio model with a free-flyer root, the names
of its two sole frames, the grasp points of its hands (added as Pinocchio frames), the camera
frame, a reference posture, the foot rectangle and the dofs that never move in planning (the
gripper fingers). :func:`walking_robot` builds it from a robot's robot.yaml.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from marionette.footsteps.errors import InvalidProblem


@dataclass(frozen=True)
class FootShape:
    """Rectangle of a sole on the floor, centred on the sole frame [m].

    ``length`` runs along the sole frame's x (toes forward), ``width`` along its y.
    """

    length: float
    width: float

    def __post_init__(self) -> None:
        if not (self.length > 0.0 and self.width > 0.0):
            raise InvalidProblem(
                f"foot length and width must be > 0, got {self.length}, {self.width}"
            )

    def corners(self) -> np.ndarray:
        """The 4 corners in the sole frame, counter-clockwise from front-left: (4, 2) [m]."""
        hl, hw = 0.5 * self.length, 0.5 * self.width
        return np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])


@dataclass
class RobotDescription:
    """A legged robot for the footstep optimiser.

    ``model`` has a free-flyer root (nq = nv + 1); ``hand_frames`` maps "left"/"right" to frames
    of ``model`` placed at the grasp point of each hand; ``frozen_joints`` are joint names kept
    at ``reference_posture`` by the optimiser (e.g. gripper fingers, whose limits are not
    reachable-pose constraints).
    """

    name: str
    model: pin.Model
    sole_frames: dict[str, str]  # {"left": ..., "right": ...}
    hand_frames: dict[str, str]  # {"left": ..., "right": ...} grasp points
    camera_frame: str  # optical frame: z forward, x right, y down
    reference_posture: np.ndarray  # (nq,)
    foot: FootShape
    frozen_joints: tuple[str, ...] = ()
    data: pin.Data = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.model.joints[1].shortname() != "JointModelFreeFlyer":
            raise InvalidProblem(f"{self.name}: the model root must be a free-flyer joint")
        for name in [*self.sole_frames.values(), *self.hand_frames.values(), self.camera_frame]:
            if not self.model.existFrame(name):
                raise InvalidProblem(f"{self.name}: no frame named {name!r} in the model")
        if set(self.sole_frames) != {"left", "right"}:
            raise InvalidProblem(f"{self.name}: sole_frames needs keys 'left' and 'right'")
        if self.reference_posture.shape != (self.model.nq,):
            raise InvalidProblem(
                f"{self.name}: reference_posture has shape {self.reference_posture.shape}, "
                f"expected ({self.model.nq},)"
            )
        for joint in self.frozen_joints:
            if not self.model.existJointName(joint):
                raise InvalidProblem(f"{self.name}: no joint named {joint!r} to freeze")
        self.data = self.model.createData()

    def frozen_velocity_indices(self) -> np.ndarray:
        """Tangent-space indices (into v, nv) of the frozen joints."""
        idx = [self.model.idx_vs[self.model.getJointId(j)] for j in self.frozen_joints]
        return np.array(sorted(idx), dtype=int)


def walking_robot(name: str) -> RobotDescription:
    """Robot ``name`` for footstep planning, from its robot.yaml: its two feet (``feet``, left
    first), the grasp points of its hands (``walking.hands``: side -> gripper, a frame added at
    the gripper frame's origin), its first camera, its reference posture, the foot rectangle
    the optimiser keeps clear (``walking.planning_foot_size``, else the sole) and the joints it
    never moves (``walking.frozen_joints``)."""
    from marionette import robots

    desc = robots.robot(name)
    where = desc.semantics
    if len(desc.feet) != 2 or desc.base != "free_flyer":
        raise InvalidProblem(
            f"{where}: footstep planning needs a free_flyer base and two feet (left, right)"
        )
    if desc.camera_frame is None:
        raise InvalidProblem(f"{where}: footstep planning needs a camera (the gaze task)")
    model, _ = robots.load_pinocchio(name, with_collision=False)
    q_ref = robots.reference_configuration(name, model)
    model = pin.Model(model)  # own copy: we add frames
    sem = robots.semantics(name)
    hand_frames = {}
    for side, gripper_name in (desc.walking.get("hands") or {}).items():
        gripper = sem.gripper(gripper_name)
        parent = model.frames[model.getFrameId(gripper.link)]
        frame = f"{side}_grasp_point"
        placement = parent.placement * pin.SE3(np.eye(3), np.array(gripper.pose.xyz))
        model.addFrame(
            pin.Frame(
                frame,
                parent.parentJoint,
                model.getFrameId(parent.name),
                placement,
                pin.FrameType.OP_FRAME,
            )
        )
        hand_frames[side] = frame
    size = desc.walking.get("planning_foot_size") or desc.feet[0].size
    return RobotDescription(
        name=desc.name,
        model=model,
        sole_frames={f.name: f.frame for f in desc.feet},
        hand_frames=hand_frames,
        camera_frame=desc.camera_frame,
        reference_posture=q_ref,
        foot=FootShape(length=size[0], width=size[1]),
        frozen_joints=tuple(desc.walking.get("frozen_joints", ())),
    )
