"""From plan to execution (thesis 000 §3.2.2, §3.2.5, §3.3.6): the plan's elementary paths
grouped into steps (one per transition crossed), one controller spec per step (the factory),
task references sampled at the controller rate and streamed ahead (Agimus-HPP), the supervisor
FSM that switches controllers with start and end checks, and the initial-state estimation.

| module | job |
|---|---|
| `plan_steps.py` | steps of a plan (consecutive paths of one transition), plan q -> robot q |
| `factory.py` | constraint kinds -> task kinds, one ControllerSpec per step, spec file + checks |
| `references.py` | time law of a step and its task references at 1 kHz (Pinocchio) |
| `streamer.py` | chunks on TASK_REFERENCE, ahead of the controller's clock |
| `supervisor.py` | the FSM: start check, streaming, end check, grasp welds, events, LCM state |
| `estimation.py` | nearest graph state of a measured configuration, steps already done |
| `monitor.py` | execution monitor: grasp / placement residuals from OBJECT_POSES -> `left_manifold` |
| `force_event.py` | `force_threshold` events from a joint's effort in ROBOT_STATE (eq. 3.11-3.13) |
| `grip_force.py` | the grip force a gripper holds: effort estimate (eq. 3.11-3.13) and MuJoCo contact forces on its jaws |
| `cli.py` | `marionette supervise`, `marionette fsm state|events|inject` |
| `demo.py`, `report.py`, `demo_cli.py` | `marionette demo <scenario>` and its report |
| `visual_servo.py` | vision in the loop: PBVS correction of the carried object's gripper task, head gaze (§5.3.1) |
| `perturbations.py` | seeded trial perturbations: displacement, slip, encoder offsets, camera noise (issue #10) |
| `drill.py` | `marionette demo drill`: align on reference holes R1, R2, interpolate the rest (§6.3) |
"""
