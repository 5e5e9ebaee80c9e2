#pragma once
/// LCM channel names, listed once in lcmtypes/CHANNELS.md (python/marionette/channels.py
/// holds the same constants; tests/python/lcm/test_channels.py checks that all three agree).

namespace marionette::channels {

inline constexpr char kRobotState[] = "ROBOT_STATE";
inline constexpr char kRobotCommand[] = "ROBOT_COMMAND";
inline constexpr char kControllerStatus[] = "CONTROLLER_STATUS";
inline constexpr char kControllerSpec[] = "CONTROLLER_SPEC";
inline constexpr char kTaskReference[] = "TASK_REFERENCE";
inline constexpr char kCommand[] = "COMMAND";
inline constexpr char kCameraHead[] = "CAMERA_HEAD";
inline constexpr char kCameraSceneRgbd[] = "CAMERA_SCENE_RGBD";
inline constexpr char kAprilTagDetections[] = "APRILTAG_DETECTIONS";
inline constexpr char kObjectPoses[] = "OBJECT_POSES";
inline constexpr char kFootstepPlan[] = "FOOTSTEP_PLAN";
inline constexpr char kWalkStatus[] = "WALK_STATUS";
inline constexpr char kSupervisorState[] = "SUPERVISOR_STATE";
inline constexpr char kSupervisorEvent[] = "SUPERVISOR_EVENT";
inline constexpr char kSupervisorDecision[] = "SUPERVISOR_DECISION";
inline constexpr char kPlannedPath[] = "PLANNED_PATH";
inline constexpr char kSimCommand[] = "SIM_COMMAND";
inline constexpr char kSimObjectPoses[] = "SIM_OBJECT_POSES";
inline constexpr char kRangeFinders[] = "RANGE_FINDERS";
inline constexpr char kDgRequest[] = "DG_REQUEST";
inline constexpr char kDgReply[] = "DG_REPLY";
inline constexpr char kDgTrace[] = "DG_TRACE";
inline constexpr char kControllerTiming[] = "CONTROLLER_TIMING";
inline constexpr char kControllerJournal[] = "CONTROLLER_JOURNAL";
inline constexpr char kDriverState[] = "DRIVER_STATE";
inline constexpr char kDriverCommand[] = "DRIVER_COMMAND";
inline constexpr char kDriverStatus[] = "DRIVER_STATUS";

}  // namespace marionette::channels
