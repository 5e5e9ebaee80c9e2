#include "marionette/controller/robots.h"

#include <sstream>
#include <stdexcept>

namespace marionette::controller {
namespace {

RobotInfo Talos(const std::string& dir) {
  RobotInfo r;
  r.name = "talos";
  r.base = "free_flyer";
  r.reference = "half_sitting";
  r.contact_bodies = {"left_sole_link", "right_sole_link"};
  r.camera = "head_rgbd";
  r.camera_frame = "rgbd_rgb_optical_frame";
  r.grippers = {{"talos/left_gripper", "gripper_left_joint", -0.02, -1.0},
                {"talos/right_gripper", "gripper_right_joint", -0.02, -1.0}};
  // Both jaws of each gripper: the "double" jaw (two fingertips) and the "single" one.
  for (const char* side : {"left", "right"}) {
    for (const char* link : {"motor_double", "inner_double", "fingertip_1", "fingertip_2",
                             "motor_single", "inner_single", "fingertip_3"}) {
      r.grip_bodies.push_back(std::string("gripper_") + side + "_" + link + "_link");
    }
  }
  return r;
}

RobotInfo Tiago(const std::string& dir) {
  RobotInfo r;
  r.name = "tiago";
  r.base = "planar";
  r.reference = "home";
  r.camera = "head_rgbd";
  r.camera_frame = "xtion_rgb_optical_frame";
  return r;
}

RobotInfo Ur10(const std::string& dir) {
  RobotInfo r;
  r.name = "ur10";
  r.base = "fixed";
  r.reference = "home";
  r.grippers = {{"ur10/gripper", "finger_joint", 0.0, 0.04}};
  // Both fingers: finger_right_link moves in MuJoCo only (a mimic of finger_joint).
  r.grip_bodies = {"finger_left_link", "finger_right_link"};
  return r;
}

}  // namespace

std::vector<std::string> RobotNames() { return {"talos", "tiago", "ur10"}; }

RobotInfo FindRobot(const std::string& name, const std::string& models_dir) {
  RobotInfo r;
  if (name == "talos") {
    r = Talos(models_dir);
  } else if (name == "tiago") {
    r = Tiago(models_dir);
  } else if (name == "ur10") {
    r = Ur10(models_dir);
  } else {
    std::string known;
    for (const std::string& n : RobotNames()) known += (known.empty() ? "" : ", ") + n;
    throw std::invalid_argument("unknown robot '" + name + "'; known robots: " + known);
  }
  const std::string base = models_dir + "/" + name + "/" + name;
  r.urdf = base + ".urdf";
  r.srdf = base + ".srdf";
  r.mjcf = base + ".xml";
  return r;
}

std::vector<int> HeldBaseVelocities(const RobotInfo& robot) {
  if (robot.base == "planar") return {0, 1, 2};  // JointModelPlanar: vx vy wz, the first 3 of v
  return {};
}

std::string ToJson(const RobotInfo& r) {
  std::ostringstream os;
  const auto list = [&os](const std::vector<std::string>& v) {
    os << '[';
    for (size_t i = 0; i < v.size(); ++i) os << (i ? ", " : "") << '"' << v[i] << '"';
    os << ']';
  };
  os << "{\"name\": \"" << r.name << "\", \"urdf\": \"" << r.urdf << "\", \"srdf\": \"" << r.srdf
     << "\", \"mjcf\": \"" << r.mjcf << "\", \"base\": \"" << r.base << "\", \"reference\": \""
     << r.reference << "\", \"contact_bodies\": ";
  list(r.contact_bodies);
  os << ", \"camera\": \"" << r.camera << "\", \"camera_frame\": \"" << r.camera_frame
     << "\", \"grippers\": [";
  for (size_t i = 0; i < r.grippers.size(); ++i) {
    const GripperInfo& g = r.grippers[i];
    os << (i ? ", " : "") << "{\"name\": \"" << g.name << "\", \"joint\": \"" << g.joint
       << "\", \"open_position\": " << g.open_position
       << ", \"closed_position\": " << g.closed_position << '}';
  }
  os << "]}";
  return os.str();
}

}  // namespace marionette::controller
