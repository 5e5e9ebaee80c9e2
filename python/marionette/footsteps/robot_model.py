"""The robot seen by the footstep optimiser: Pinocchio model, sole / hand / camera frames, feet.

Only the pieces the augmented robot needs: a Pinocchio model with a free-flyer root, the names
of its two sole frames, the grasp points of its hands (added as Pinocchio frames), the camera
frame, a reference posture, the foot rectangle and the dofs that never move in planning (the
gripper fingers). :func:`talos` builds it for TALOS from example-robot-data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

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


# TALOS ----------------------------------------------------------------------------------------
# Grasp point of the TALOS gripper in gripper_<side>_base_link: between the fingertips, which
# sit 0.12 m along -z of that frame (measured on the URDF in half_sitting).
TALOS_GRASP_POINT = np.array([0.0, 0.0, -0.12])
# Sole box of talos_reduced_box.urdf (0.21 x 0.13 m), centred on <side>_sole_link.
TALOS_FOOT = FootShape(length=0.21, width=0.13)


def _talos_data_dir() -> Path:
    # example-robot-data 6 ships data only, in the cmeel prefix that also holds pinocchio:
    # <prefix>/lib/python3.X/site-packages/pinocchio -> <prefix>/share/example-robot-data.
    prefix = Path(pin.__file__).resolve().parents[4]
    candidate = prefix / "share/example-robot-data/robots/talos_data"
    if not candidate.is_dir():
        raise InvalidProblem(
            f"example-robot-data's talos_data not found at {candidate} (scripts/setup installs it)"
        )
    return candidate


def _load_talos_model() -> tuple[pin.Model, np.ndarray]:
    """TALOS (talos_reduced) with a free-flyer root and its half_sitting posture."""
    try:  # the shared loader (marionette.robots), once its generated models exist
        from marionette import robots

        if not robots.robot("talos").urdf.is_file():
            raise FileNotFoundError(robots.robot("talos").urdf)
        model, _ = robots.load_pinocchio("talos", with_collision=False)
        return model, robots.reference_configuration("talos", model)
    except (ImportError, AttributeError, KeyError, TypeError, ValueError, OSError):
        pass
    directory = _talos_data_dir()
    model = pin.buildModelFromUrdf(
        str(directory / "robots/talos_reduced.urdf"), pin.JointModelFreeFlyer()
    )
    pin.loadReferenceConfigurations(model, str(directory / "srdf/talos.srdf"))
    return model, model.referenceConfigurations["half_sitting"].copy()


def talos() -> RobotDescription:
    """TALOS for footstep planning: soles, grasp points, head camera, half_sitting posture."""
    model, q_ref = _load_talos_model()
    model = pin.Model(model)  # own copy: we add frames
    hand_frames = {}
    for side in ("left", "right"):
        parent = model.frames[model.getFrameId(f"gripper_{side}_base_link")]
        name = f"{side}_grasp_point"
        if not model.existFrame(name):
            placement = parent.placement * pin.SE3(np.eye(3), TALOS_GRASP_POINT)
            model.addFrame(
                pin.Frame(
                    name,
                    parent.parentJoint,
                    model.getFrameId(parent.name),
                    placement,
                    pin.FrameType.OP_FRAME,
                )
            )
        hand_frames[side] = name
    return RobotDescription(
        name="talos",
        model=model,
        sole_frames={"left": "left_sole_link", "right": "right_sole_link"},
        hand_frames=hand_frames,
        camera_frame="rgbd_rgb_optical_frame",
        reference_posture=q_ref,
        foot=TALOS_FOOT,
        frozen_joints=("gripper_left_joint", "gripper_right_joint"),
    )
