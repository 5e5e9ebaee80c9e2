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
| `monitor.py` | grasp / placement residuals from OBJECT_POSES -> `left_manifold` events |
| `force_event.py` | `force_threshold` events from a joint's effort in ROBOT_STATE (eq. 3.11-3.13) |
| `grip_force.py` | a gripper's grip force: effort estimate (eq. 3.11-3.13), jaw contact forces |
| `grip_monitor.py` | fingers closed on nothing (the encoder) -> `grasp_lost` events |
| `step_follower.py` | the supervisor's running step from SUPERVISOR_STATE (for the monitors) |
| `cli.py` | `marionette supervise`, `marionette fsm state|events|inject` |
| `visual_servo.py` | PBVS correction of a carried object's gripper task, head gaze (§5.3.1) |
| `tool_task.py` | a tool held by an arm: one streamed SE3 task, corrected on its measured pose |
| `walking.py` | the walking controller spec; ZMP in the support polygon; merged footstep plans |
| `errors.py` | `ExecutionError` |

The experiments run on this runtime are in :mod:`marionette.scenarios`.
"""
