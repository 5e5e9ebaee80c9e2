// MujocoScene / MujocoDevice: the Pinocchio <-> MuJoCo state map (against MuJoCo's own body
// velocities), and TALOS standing on its sole boxes under the position servos (contact forces
// against its weight, base drift, ZMP inside the feet).
#include <gtest/gtest.h>

#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/parsers/srdf.hpp>
#include <pinocchio/parsers/urdf.hpp>
#include <pinocchio/spatial/explog.hpp>

#include <cmath>
#include <random>

#include "marionette/graph/graph.h"
#include "marionette/sim/mujoco_device.h"

namespace marionette::sim {
namespace {

namespace pin = pinocchio;
const std::string kModels = MARIONETTE_MODELS_DIR;

pin::Model LoadTalos() {
  pin::Model model;
  pin::urdf::buildModel(kModels + "/talos/talos.urdf", pin::JointModelFreeFlyer(), model);
  pin::srdf::loadReferenceConfigurations(model, kModels + "/talos/talos.srdf", false);
  return model;
}

// half_sitting with the soles on the floor (z = 0).
Eigen::VectorXd StandingConfiguration(const pin::Model& model) {
  pin::Data data(model);
  Eigen::VectorXd q = model.referenceConfigurations.at("half_sitting");
  pin::framesForwardKinematics(model, data, q);
  q[2] -= data.oMf[model.getFrameId("left_sole_link")].translation().z();
  return q;
}

// A push is a force on the body for a duration: against Newton's closed form. The UR10 scene's
// 0.3 kg box, resting on the table, pushed up with F > m g for T: it rises a T^2 / 2 while pushed
// (a = F / m - g), then (a T)^2 / (2 g) in flight, and the push ends on time (it lands, at rest).
TEST(MujocoSceneTest, APushLiftsAFreeBoxAsNewtonSays) {
  pin::Model model;
  pin::urdf::buildModel(kModels + "/ur10/ur10.urdf", model);
  MujocoScene scene(kModels + "/scenes/ur10_box.xml", model);
  const Eigen::VectorXd q0 = [&] {
    Eigen::VectorXd q(model.nq), v(model.nv);
    scene.ReadRobotState(q, v);
    return q;
  }();
  const Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.nv);
  const int box = scene.BodyId("box");
  const double mass = scene.model().body_subtreemass[box];
  const double g = -scene.model().opt.gravity[2];
  auto step = [&] {
    scene.Step1();
    scene.WriteServoTargets(q0, v0);  // the arm holds still
    scene.Step2(1);
  };
  for (int i = 0; i < 500; ++i) step();  // settle on the table
  const double z0 = scene.BodyPose("box").translation().z();
  const double force = 5.0, duration = 0.1;
  scene.Push(box, Eigen::Vector3d(0.0, 0.0, force), duration);
  double peak = z0;
  for (int i = 0; i < 600; ++i) {
    step();
    peak = std::max(peak, scene.BodyPose("box").translation().z());
  }
  const double a = force / mass - g;
  const double expected = 0.5 * a * duration * duration + std::pow(a * duration, 2) / (2.0 * g);
  EXPECT_NEAR(peak - z0, expected, 0.03 * expected) << "mass " << mass << " kg";
  EXPECT_NEAR(scene.BodyPose("box").translation().z(), z0, 1e-3);  // landed: the push ended
  EXPECT_THROW(scene.Push(box, Eigen::Vector3d(NAN, 0.0, 0.0), 0.1), SimError);
  EXPECT_THROW(scene.Push(0, Eigen::Vector3d::UnitZ(), 0.1), SimError);
}

// Coulomb's law decides what a horizontal push does to the box on the table: held at its scene
// friction (F < mu m g), slid once SetFriction makes it slippery (mu'): a = F / m - mu' g while
// pushed for T, then it brakes at mu' g, a distance a T^2 / 2 + (a T)^2 / (2 mu' g) in all.
TEST(MujocoSceneTest, AFrictionChangeLetsAPushSlideTheBoxAsCoulombSays) {
  pin::Model model;
  pin::urdf::buildModel(kModels + "/ur10/ur10.urdf", model);
  MujocoScene scene(kModels + "/scenes/ur10_box.xml", model);
  Eigen::VectorXd q0(model.nq), v(model.nv);
  scene.ReadRobotState(q0, v);
  const Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.nv);
  const int box = scene.BodyId("box");
  const double mass = scene.model().body_subtreemass[box];
  const double g = -scene.model().opt.gravity[2];
  auto run = [&](int ticks) {
    for (int i = 0; i < ticks; ++i) {
      scene.Step1();
      scene.WriteServoTargets(q0, v0);  // the arm holds still
      scene.Step2(1);
    }
  };
  auto x = [&] { return scene.BodyPose("box").translation().x(); };
  run(500);  // settle on the table
  const double force = 0.3 * mass * g, duration = 0.2, dt = scene.timestep();
  double x0 = x();
  scene.Push(box, Eigen::Vector3d(force, 0.0, 0.0), duration);
  run(static_cast<int>(1.0 / dt));
  EXPECT_LT(std::abs(x() - x0), 1e-3) << "held by the scene's friction";
  const double mu = 0.2;
  scene.SetFriction(box, mu);
  x0 = x();
  scene.Push(box, Eigen::Vector3d(force, 0.0, 0.0), duration);
  run(static_cast<int>(duration / dt));
  const double a = force / mass - mu * g;
  const double pushed = 0.5 * a * duration * duration;
  EXPECT_NEAR(x() - x0, pushed, 0.05 * pushed) << "mass " << mass << " kg";
  run(static_cast<int>(1.0 / dt));
  const double expected = pushed + std::pow(a * duration, 2) / (2 * mu * g);
  EXPECT_NEAR(x() - x0, expected, 0.05 * expected);
  EXPECT_THROW(scene.SetFriction(box, -0.1), SimError);
  EXPECT_THROW(scene.SetFriction(box, NAN), SimError);
  EXPECT_THROW(scene.SetFriction(0, 0.5), SimError);
}

// A slide carries a mocap fixture (the step-over's bar) at constant speed: after a fraction s of
// the duration it is a fraction s of the way (position linear, orientation the shorter rotation's
// s), it stops exactly on the target, and a free body or a non-finite pose is refused.
TEST(MujocoSceneTest, ASlideCarriesAMocapBodyAtConstantSpeedOntoItsTarget) {
  const pin::Model model = LoadTalos();
  MujocoScene scene(kModels + "/scenes/talos_walk.xml", model);
  const int bar = scene.BodyId("bar");
  const pin::SE3 from = scene.BodyPose("bar");
  const double yaw = 0.3, duration = 0.5, dt = scene.timestep();
  const pin::SE3 to(
      Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * from.rotation(),
      from.translation() + Eigen::Vector3d(0.2, -0.1, 0.0));
  scene.Slide(bar, to, duration);
  const Eigen::VectorXd q0 = StandingConfiguration(model);
  const Eigen::VectorXd v0 = Eigen::VectorXd::Zero(model.nv);
  auto run = [&](int ticks) {
    for (int i = 0; i < ticks; ++i) {
      scene.Step1();
      scene.WriteServoTargets(q0, v0);
      scene.Step2(1);
    }
  };
  int ticks = 0;
  for (const double s : {0.25, 0.5, 1.0}) {
    const int until = static_cast<int>(std::lround(s * duration / dt));
    run(until - ticks);
    ticks = until;
    mj_kinematics(&scene.model(), &scene.mutable_data());
    const pin::SE3 X = scene.BodyPose("bar");
    EXPECT_NEAR((X.translation() - from.translation()).norm(),
                s * (to.translation() - from.translation()).norm(), 1e-9)
        << "at " << s << " of the slide";
    const double turned = pin::log3(from.rotation().transpose() * X.rotation()).norm();
    EXPECT_NEAR(turned, s * yaw, 1e-9) << "at " << s << " of the slide";
  }
  run(100);  // it stays on the target
  mj_kinematics(&scene.model(), &scene.mutable_data());
  EXPECT_TRUE(scene.BodyPose("bar").isApprox(to, 1e-9));
  EXPECT_THROW(scene.Slide(scene.BodyId("base_link"), to, 1.0), SimError);
  EXPECT_THROW(scene.Slide(bar, to, NAN), SimError);
  EXPECT_THROW(scene.Slide(bar, to, -1.0), SimError);
}

TEST(MujocoSceneTest, StateRoundTripsAndVelocityConventionsMatchMujoco) {
  const pin::Model model = LoadTalos();
  MujocoScene scene(kModels + "/talos/talos.xml", model);
  std::mt19937 rng(7);
  std::normal_distribution<double> normal;
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::VectorXd q = pin::randomConfiguration(model, model.lowerPositionLimit.cwiseMax(-3.0),
                                                 model.upperPositionLimit.cwiseMin(3.0));
    Eigen::VectorXd v(model.nv);
    for (int i = 0; i < model.nv; ++i) v[i] = normal(rng);
    scene.WriteRobotState(q, v);
    Eigen::VectorXd q2(model.nq), v2(model.nv);
    scene.ReadRobotState(q2, v2);
    EXPECT_TRUE(q2.isApprox(q, 1e-12)) << trial;
    EXPECT_TRUE(v2.isApprox(v, 1e-12)) << trial;
    // Independent check: MuJoCo's own 6D velocity of the base body frame (mjOBJ_XBODY: the
    // body frame, not its inertial frame), in that frame, angular first, equals Pinocchio's
    // free-flyer velocity (linear first, base frame).
    mjtNum vel[6];
    mj_objectVelocity(&scene.model(), &scene.data(), mjOBJ_XBODY, scene.BodyId("base_link"), vel,
                      1);
    EXPECT_NEAR((Eigen::Map<Eigen::Vector3d>(vel + 3) - v.head<3>()).norm(), 0.0, 1e-9);
    EXPECT_NEAR((Eigen::Map<Eigen::Vector3d>(vel) - v.segment<3>(3)).norm(), 0.0, 1e-9);
    // And a link pose against Pinocchio's forward kinematics.
    pin::Data data(model);
    pin::framesForwardKinematics(model, data, q);
    const pin::SE3 X = scene.BodyPose("arm_left_7_link");
    EXPECT_TRUE(X.isApprox(data.oMf[model.getFrameId("arm_left_7_link")], 1e-9));
  }
}

TEST(MujocoSceneTest, EncoderOffsetsGiveTheControllerTheTrueJointPositions) {
  const pin::Model model = LoadTalos();
  MujocoScene scene(kModels + "/talos/talos.xml", model);
  const std::string joint = "arm_left_1_joint";
  const double delta = 0.12;  // [rad] the encoder reads 7 deg above the truth
  const int jnt = mj_name2id(&scene.model(), mjOBJ_JOINT, joint.c_str());
  const int adr = scene.model().jnt_qposadr[jnt];
  // MuJoCo turns a hinge by qpos - qpos0: this is <joint ref="0.12">, the offset scenes'
  // encoder error (marionette.scenarios.perturbations.scene_with_joint_offsets).
  const_cast<mjModel&>(scene.model()).qpos0[adr] = delta;
  const Eigen::VectorXd q = StandingConfiguration(model);
  const int iq = model.joints[model.getJointId(joint)].idx_q();
  pin::Data data(model);
  const auto arm_pose_error = [&](const Eigen::VectorXd& q_model) {
    pin::framesForwardKinematics(model, data, q_model);
    return (scene.BodyPose("arm_left_7_link").translation() -
            data.oMf[model.getFrameId("arm_left_7_link")].translation())
        .norm();
  };
  Eigen::VectorXd q_read(model.nq), v_read(model.nv);

  scene.SetEncoderOffsets({{joint, delta}});
  scene.WriteRobotState(q, Eigen::VectorXd::Zero(model.nv));
  EXPECT_NEAR(scene.data().qpos[adr], q[iq] + delta, 1e-12);  // what the encoder reads
  scene.ReadRobotState(q_read, v_read);
  EXPECT_TRUE(q_read.isApprox(q, 1e-12));
  EXPECT_LT(arm_pose_error(q_read), 1e-9);  // the controller's model sees the true arm
  scene.WriteServoTargets(q, Eigen::VectorXd::Zero(model.nv));
  const int act = mj_name2id(&scene.model(), mjOBJ_ACTUATOR, joint.c_str());
  ASSERT_GE(act, 0);
  EXPECT_NEAR(scene.data().ctrl[act], q[iq] + delta, 1e-12);

  scene.SetEncoderOffsets({});  // uncalibrated: the model puts the wrist centimetres off
  scene.ReadRobotState(q_read, v_read);
  EXPECT_NEAR(q_read[iq], q[iq] + delta, 1e-12);
  EXPECT_GT(arm_pose_error(q_read), 0.02);

  EXPECT_THROW(scene.SetEncoderOffsets({{"no_such_joint", 0.1}}), SimError);
  EXPECT_THROW(scene.SetEncoderOffsets({{joint, std::nan("")}}), SimError);
}

TEST(MujocoSceneTest, AReleasedHandStopsCollidingUntilItIsClearOfTheObject) {
  const pin::Model model = LoadTalos();
  MujocoScene scene(kModels + "/scenes/talos_plank.xml", model);
  const mjModel& m = scene.model();
  const int weld = scene.WeldId("grasp/talos/left_gripper/plank");
  const int hand = mj_name2id(&m, mjOBJ_BODY, "gripper_left_base_link");
  int finger = -1;  // a colliding geom of the hand's subtree
  for (int g = 0; g < m.ngeom && finger < 0; ++g) {
    for (int b = m.geom_bodyid[g]; b > 0; b = m.body_parentid[b]) {
      if (b == hand && m.geom_contype[g] != 0) finger = g;
    }
  }
  ASSERT_GE(finger, 0);
  const int contype = m.geom_contype[finger], conaffinity = m.geom_conaffinity[finger];
  const auto step = [&] {
    scene.Step1();
    scene.Step2(1);
  };
  scene.SetWeld(weld, true);
  EXPECT_EQ(scene.opening_hands(), 0);
  scene.SetWeld(weld, false);  // released: the hand opens
  EXPECT_EQ(scene.opening_hands(), 1);
  EXPECT_EQ(m.geom_contype[finger], 0);
  EXPECT_EQ(m.geom_conaffinity[finger], 0);
  scene.SetFreeBodyPose("plank", scene.BodyPose("gripper_left_base_link"));  // still in the jaw
  step();
  EXPECT_EQ(scene.opening_hands(), 1);
  scene.SetWeld(weld, true);  // taken again before clear: the hand is closed and collides
  EXPECT_EQ(scene.opening_hands(), 0);
  EXPECT_EQ(m.geom_contype[finger], contype);
  scene.SetWeld(weld, false);
  EXPECT_EQ(scene.opening_hands(), 1);
  EXPECT_EQ(m.geom_contype[finger], 0);
  scene.SetFreeBodyPose("plank",
                        pin::SE3(Eigen::Matrix3d::Identity(), Eigen::Vector3d(3.0, 0.0, 1.0)));
  step();  // clear of the plank: the hand collides again
  EXPECT_EQ(scene.opening_hands(), 0);
  EXPECT_EQ(m.geom_contype[finger], contype);
  EXPECT_EQ(m.geom_conaffinity[finger], conaffinity);
  scene.SetWeld(weld, false);  // releasing a released weld opens nothing
  EXPECT_EQ(scene.opening_hands(), 0);
}

TEST(MujocoDeviceTest, TalosStandsOnItsSolesUnderTheServos) {
  const pin::Model model = LoadTalos();
  MujocoScene scene(kModels + "/talos/talos.xml", model);
  const Eigen::VectorXd q0 = StandingConfiguration(model);
  scene.WriteRobotState(q0, Eigen::VectorXd::Zero(model.nv));

  graph::GraphBuilder b;
  auto& device = b.Add<MujocoDevice>(
      "device", &scene, std::vector<std::string>{"left_sole_link", "right_sole_link"}, 1e-3);
  device.q_command_input().SetValue(q0);  // hold half-sitting
  auto graph = b.Build();

  pin::Data data(model);
  const double weight = pin::computeTotalMass(model) * 9.81;
  double fz_sum = 0.0, zmp_violations = 0.0;
  int samples = 0;
  graph::Tick t;
  for (; t.index < 3000; ++t) {
    device.Read(t);
    graph->Evaluate(t);
    device.Write(t);
    if (t.index >= 2000) {  // settled: the last second
      const Eigen::VectorXd& wl = device.wrench_output(0).value();
      const Eigen::VectorXd& wr = device.wrench_output(1).value();
      fz_sum += wl[2] + wr[2];
      ++samples;
      // ZMP of each foot from its wrench about the sole origin: p = (-ty / fz, tx / fz).
      for (const Eigen::VectorXd* w : {&wl, &wr}) {
        if ((*w)[2] < 1.0) continue;
        const double zx = -(*w)[4] / (*w)[2], zy = (*w)[3] / (*w)[2];
        // Soles are 0.205 x 0.122 m boxes centred on the sole frame (models/talos/talos.xml).
        if (std::abs(zx) > 0.1025 || std::abs(zy) > 0.061) zmp_violations += 1;
      }
    }
  }
  const Eigen::VectorXd& q = device.q_output().value();
  EXPECT_LT((q.head<2>() - q0.head<2>()).norm(), 0.01) << "base drift in x, y";
  EXPECT_NEAR(q[2], q0[2], 0.01) << "base height";
  EXPECT_NEAR(fz_sum / samples, weight, 0.02 * weight) << "the soles carry the robot's weight";
  EXPECT_EQ(zmp_violations, 0) << "each foot's centre of pressure stays under the foot";
}

}  // namespace
}  // namespace marionette::sim
