"""``ur10-box``: the UR10 picks the box with its two-finger gripper, holds it by friction with 5 N
of gripper admittance and places it 0.5 m away, open loop from the planned references
(``docs/scenarios.md``)."""

from __future__ import annotations

from marionette.scenarios.plan_and_execute import PROBLEMS_DIR, SCENES_DIR, PlanAndExecute

SCENARIO = PlanAndExecute(
    name="ur10-box",
    description="UR10 picks the box with its two-finger gripper, holds it by friction with 5 N "
    "(gripper admittance, thesis 000 §3.2.4.3) and places it 0.5 m away",
    seed_experiment="thesis 000 §3.2.4.3 (gripper admittance) on the chapter-3 flow "
    "(plan, one controller per transition, supervisor)",
    problem=PROBLEMS_DIR / "ur10_box.yaml",
    scene=SCENES_DIR / "ur10_box.xml",
    seed=0,
    object_name="box",
    max_joint_velocity=1.0,
    gripper_admittance=True,
    friction_grasps=True,
)
