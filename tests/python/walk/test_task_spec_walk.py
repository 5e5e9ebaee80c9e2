"""TaskSpec.reference_channel: the walk's references name the controller's pattern
generator; they round-trip through lcmt_task_spec and bad values are refused with their reason
before the controller sees them (the controller's own refusals: controller_factory.cc)."""

from __future__ import annotations

import pytest

from marionette import channels, lcmt_task_spec
from marionette.control.spec import ControllerSpec, SpecError, TaskSpec


def walking_tasks() -> list[TaskSpec]:
    return [
        TaskSpec(
            "left_foot",
            "se3",
            0,
            frame="left_sole_link",
            gain=20.0,
            reference_channel="walk:left_foot",
        ),
        TaskSpec(
            "right_foot",
            "se3",
            0,
            frame="right_sole_link",
            gain=20.0,
            reference_channel="walk:right_foot",
        ),
        TaskSpec("com", "com", 0, gain=5.0, reference_channel="walk:com"),
        TaskSpec(
            "waist",
            "se3",
            0,
            frame="base_link",
            mask=(False, False, False, True, True, False),
            gain=20.0,
        ),
        TaskSpec("arm", "se3", 1, frame="arm_right_7_link", streamed=True),
        TaskSpec(
            "posture",
            "posture",
            1,
            gain=2.0,
            reference=(0.1,) * 3,
            joints=("torso_1_joint", "torso_2_joint", "head_1_joint"),
        ),
    ]


def test_reference_channels_round_trip_through_lcm():
    spec = ControllerSpec(3, "walk", walking_tasks())
    wire = lcmt_task_spec.decode(spec.to_lcm().tasks[0].encode())
    assert wire.reference_channel == "walk:left_foot"
    msg = spec.to_lcm()
    assert [t.reference_channel for t in msg.tasks] == [
        "walk:left_foot",
        "walk:right_foot",
        "walk:com",
        "",
        channels.TASK_REFERENCE,
        "",
    ]
    back = [TaskSpec.from_lcm(lcmt_task_spec.decode(t.encode())) for t in msg.tasks]
    assert back == spec.tasks
    # YAML/JSON form (the factory's controllers.yaml): the channel travels too.
    again = ControllerSpec.from_dict(spec.to_dict())
    assert again.to_dict() == spec.to_dict()
    assert [t.reference_channel for t in again.tasks][:3] == [
        "walk:left_foot",
        "walk:right_foot",
        "walk:com",
    ]


@pytest.mark.parametrize(
    "task, reason",
    [
        (
            TaskSpec("f", "se3", 0, frame="left_sole_link", reference_channel="walk:left_hand"),
            "unknown reference_channel 'walk:left_hand'",
        ),
        (
            TaskSpec(
                "f", "se3", 0, frame="left_sole_link", reference_channel=channels.TASK_REFERENCE
            ),
            "streamed=True for TASK_REFERENCE",
        ),
        (
            TaskSpec("c", "position", 0, frame="base_link", reference_channel="walk:com"),
            "a 'walk:com' reference needs a com task, not position",
        ),
        (
            TaskSpec(
                "f",
                "se3",
                0,
                frame="left_sole_link",
                reference_channel="walk:left_foot",
                streamed=True,
            ),
            "no streamed or fixed reference",
        ),
        (
            TaskSpec("c", "com", 0, reference_channel="walk:com", reference=(0.0, 0.0, 0.8)),
            "no streamed or fixed reference",
        ),
    ],
)
def test_bad_walk_references_are_refused_with_their_reason(task, reason):
    with pytest.raises(SpecError, match=reason.replace("(", r"\(").replace(")", r"\)")) as err:
        task.to_lcm()
    assert "task 'f'" in str(err.value) or "task 'c'" in str(err.value)
