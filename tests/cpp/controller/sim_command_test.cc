// SIM_COMMAND as both simulators read it (sim_start.h, ReadSimCommand): a slide names a mocap
// body of the scene and gives a unit pose and a finite duration; anything else is refused with
// one line that says what slide moves.
#include <gtest/gtest.h>

#include <cmath>
#include <pinocchio/parsers/urdf.hpp>
#include <string>
#include <variant>

#include "marionette/controller/sim_start.h"

namespace marionette::controller {
namespace {

const std::string kModels = MARIONETTE_MODELS_DIR;

lcmt_sim_command Slide(const std::string& body, double duration) {
  lcmt_sim_command msg{};
  msg.command = "slide";
  msg.object_name = body;
  msg.position[0] = 1.2;
  msg.quaternion[0] = std::cos(0.05), msg.quaternion[3] = std::sin(0.05);
  msg.duration = duration;
  return msg;
}

TEST(SimCommandTest, ASlideMovesAMocapBodyAndAnythingElseIsRefusedInOneLine) {
  pinocchio::Model model;
  pinocchio::urdf::buildModel(kModels + "/talos/talos.urdf", pinocchio::JointModelFreeFlyer(),
                              model);
  sim::MujocoScene scene(kModels + "/scenes/talos_walk.xml", model);
  const std::vector<std::string> free_objects{"ball"};
  const std::vector<int> free_ids{scene.BodyId("ball")};

  const auto ok = ReadSimCommand(Slide("bar", 1.5), scene, free_objects, free_ids);
  ASSERT_TRUE(std::holds_alternative<SimRequest>(ok));
  const SimRequest& r = std::get<SimRequest>(ok);
  EXPECT_EQ(r.kind, SimRequest::kSlide);
  EXPECT_EQ(r.id, scene.BodyId("bar"));
  EXPECT_DOUBLE_EQ(r.duration_s, 1.5);
  EXPECT_NEAR(r.pose.translation().x(), 1.2, 1e-12);

  auto refusal = [&](const lcmt_sim_command& msg) {
    const auto read = ReadSimCommand(msg, scene, free_objects, free_ids);
    EXPECT_TRUE(std::holds_alternative<SimCommandRefusal>(read)) << msg.object_name;
    return std::holds_alternative<SimCommandRefusal>(read) ? std::get<SimCommandRefusal>(read)
                                                           : SimCommandRefusal{};
  };
  const SimCommandRefusal free_body = refusal(Slide("ball", 1.0));  // a free body is pushed, moved
  EXPECT_EQ(free_body.category, "unknown object");
  EXPECT_NE(free_body.detail.find("bar, pedestal"), std::string::npos) << free_body.detail;
  EXPECT_EQ(refusal(Slide("no_such_body", 1.0)).category, "unknown object");
  EXPECT_EQ(refusal(Slide("bar", -1.0)).category, "invalid slide");
  EXPECT_EQ(refusal(Slide("bar", NAN)).category, "invalid slide");
  lcmt_sim_command tilted = Slide("bar", 1.0);
  tilted.quaternion[0] = 2.0;  // not a unit quaternion
  EXPECT_EQ(refusal(tilted).category, "invalid pose");
  lcmt_sim_command unknown = Slide("bar", 1.0);
  unknown.command = "teleport";
  const SimCommandRefusal what = refusal(unknown);
  EXPECT_NE(what.detail.find("slide"), std::string::npos) << what.detail;
}

}  // namespace
}  // namespace marionette::controller
