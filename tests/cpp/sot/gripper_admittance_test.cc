// FeatureGripperAdmittance (thesis 000 §3.2.4.3, eq. 3.11–3.13): the force filter against the
// closed-form step response of the continuous first-order low-pass, and the whole loop in MuJoCo
// on tests/data/gripper_bench.xml (the TALOS gripper joint, servo and friction closing on a
// block) through the controller's own pieces (command integrator, RobotModel, Task, Solver,
// MujocoDevice): the grip force measured independently from MuJoCo's contacts.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <cmath>
#include <pinocchio/multibody/model.hpp>

#include "marionette/graph/graph.h"
#include "marionette/sim/mujoco_device.h"
#include "marionette/sot/feature_gripper_admittance.h"
#include "marionette/sot/kinematic_device.h"
#include "marionette/sot/robot_model.h"
#include "marionette/sot/solver.h"
#include "marionette/sot/task.h"

namespace marionette::sot {
namespace {

namespace pin = pinocchio;
const std::string kScene = std::string(MARIONETTE_TEST_DATA_DIR) + "/gripper_bench.xml";
constexpr double kLever = 0.1;         // fingertip distance to the axis in the scene [m]
constexpr double kClosed = -1.0;       // TALOS closed_position (robots.cc)
constexpr double kOpen = -0.02;        // TALOS open_position
constexpr double kFrictionLoss = 0.1;  // gripper joint frictionloss in the scene [N m]

// The bench's robot: one revolute joint about z, named like the TALOS joint and the MJCF's.
ModelPtr BenchModel() {
  auto model = std::make_shared<pin::Model>();
  model->name = "gripper_bench";
  const pin::JointIndex j = model->addJoint(
      0, pin::JointModelRZ(), pin::SE3::Identity(), "gripper_right_joint",
      Eigen::VectorXd::Constant(1, 1.0), Eigen::VectorXd::Constant(1, 1.0),
      Eigen::VectorXd::Constant(1, -1.0471975512), Eigen::VectorXd::Constant(1, 0.0));
  model->appendBodyToJoint(j, pin::Inertia::FromSphere(0.169, 0.01), pin::SE3::Identity());
  return model;
}

// Sum of the normal contact forces on geom `geom` [N] (mj_contactForce, contact frame: normal
// first).
double NormalForceOn(const mjModel& m, mjData& d, int geom) {
  double sum = 0.0;
  for (int c = 0; c < d.ncon; ++c) {
    if (d.contact[c].geom1 != geom && d.contact[c].geom2 != geom) continue;
    mjtNum f[6];
    mj_contactForce(&m, &d, c, f);
    sum += f[0];
  }
  return sum;
}

struct Bench {
  ModelPtr model = BenchModel();
  std::unique_ptr<sim::MujocoScene> scene = std::make_unique<sim::MujocoScene>(kScene, *model);
  std::unique_ptr<graph::Graph> graph;
  FeatureGripperAdmittance* feature = nullptr;
  sim::MujocoDevice* device = nullptr;
  graph::OutputSignal<Eigen::VectorXd>* velocity = nullptr;  // the solver's command (nv = 1)
  graph::Tick tick;
  int fingertip = -1;
  double command = 0.0;  // the gripper velocity the last tick commanded [rad/s]

  explicit Bench(bool with_block, GripperAdmittanceOptions options = {}) {
    const mjModel& m = scene->model();
    if (!with_block) {  // the block stops colliding: nothing between the fingers
      const int block = mj_name2id(&m, mjOBJ_GEOM, "block");
      const_cast<mjModel&>(m).geom_contype[block] = 0;
      const_cast<mjModel&>(m).geom_conaffinity[block] = 0;
    }
    fingertip = mj_name2id(&m, mjOBJ_GEOM, "fingertip");
    const Eigen::VectorXd q0 = Eigen::VectorXd::Constant(1, kOpen);
    scene->WriteRobotState(q0, Eigen::VectorXd::Zero(1));
    graph::GraphBuilder b;
    auto& command = b.Add<KinematicDevice>("command", model, q0);
    auto& robot = b.Add<RobotModel>("robot", model);
    device = &b.Add<sim::MujocoDevice>("device", scene.get(), std::vector<std::string>{}, 1e-3);
    feature = &b.Add<FeatureGripperAdmittance>("gripper", model, "gripper_right_joint", kClosed,
                                               false, options);
    auto& task = b.Add<Task>("gripper_task", *feature, Gain::Constant(options.task_gain));
    auto& solver = b.Add<Solver>("sot", 1, Solver::Levels{{&task}});
    velocity = &solver.velocity_output();
    b.Connect(command.configuration_output(), robot.configuration_input());
    b.Connect(robot.kinematics_output(), feature->kinematics_input());
    b.Connect(device->effort_output(), feature->effort_input());
    b.Connect(device->q_output(), feature->q_measured_input());
    b.Connect(solver.velocity_output(), command.command_input());
    b.Connect(command.configuration_output(), device->q_command_input());
    b.Connect(solver.velocity_output(), device->v_command_input());
    b.Connect(command.velocity_output(), solver.initial_velocity_input());
    graph = b.Build();
  }
  void Step() {
    device->Read(tick);
    graph->Evaluate(tick);
    device->Write(tick);
    command = velocity->Eval(tick)[0];
    ++tick;
  }
  // The state machine after the last tick (committed): phase and filtered force y.
  double Phase() const { return feature->output<Eigen::VectorXd>("machine").value()[0]; }
  double Filtered() const { return feature->output<Eigen::VectorXd>("machine").value()[1]; }
  // The gripper joint as MuJoCo has it (not through the entity).
  double JointPosition() const {
    const mjModel& m = scene->model();
    return scene->data().qpos[m.jnt_qposadr[mj_name2id(&m, mjOBJ_JOINT, "gripper_right_joint")]];
  }
  double ContactForce() { return NormalForceOn(scene->model(), scene->mutable_data(), fingertip); }
};

TEST(GripperAdmittanceTest, FilterIsTheExactDiscretisationOfTheFirstOrderLowPass) {
  const ModelPtr model = BenchModel();
  GripperAdmittanceOptions options;
  graph::GraphBuilder b;
  auto& robot = b.Add<RobotModel>("robot", model);
  auto& f = b.Add<FeatureGripperAdmittance>("gripper", model, "gripper_right_joint", kClosed, false,
                                            options);
  robot.configuration_input().SetValue(Eigen::VectorXd::Constant(1, kOpen));
  b.Connect(robot.kinematics_output(), f.kinematics_input());
  f.effort_input().SetValue(Eigen::VectorXd::Zero(1));
  auto g = b.Build();
  graph::Tick t;
  g->Evaluate(t);  // the filter primes at 0 N
  ++t;
  // A torque step of -0.3 N m (closing, s = -1) is f = 3 N at d = 0.1 m (eq. 3.13); the
  // continuous low-pass answers y(t) = 3 (1 − exp(−2π f_c t)) and the exact discretisation
  // matches it at every sample.
  f.effort_input().SetValue(Eigen::VectorXd::Constant(1, -0.3));
  // Read after each tick, the state holds its committed update: k + 1 samples of the step.
  for (int k = 0; k < 400; ++k, ++t) {
    g->Evaluate(t);
    EXPECT_NEAR(f.force_output().Eval(t), 3.0, 1e-12);
    const double expected =
        3.0 * (1.0 - std::exp(-2.0 * M_PI * options.cutoff_frequency * (k + 1) * 1e-3));
    ASSERT_NEAR(f.force_filtered_output().Eval(t), expected, 1e-12) << "sample " << k;
    EXPECT_EQ(f.phase_output().Eval(t), 0.0) << "3 N stays under the 4 N threshold";
  }
}

TEST(GripperAdmittanceTest, ClosesOnTheBlockAndHoldsFiveNewtons) {
  Bench bench(/*with_block=*/true);
  const GripperAdmittanceOptions& o = bench.feature->options();
  double previous_phase = 0.0, y_before_switch = -1.0, y_at_switch = -1.0, peak_contact = 0.0;
  int64_t switch_tick = -1, settled_tick = -1;
  while (bench.tick.index < 12000) {
    const graph::Tick now = bench.tick;
    bench.Step();
    const double phase = bench.Phase(), y = bench.Filtered();
    const double contact = bench.ContactForce();
    peak_contact = std::max(peak_contact, contact);
    if (std::abs(contact - 5.0) > 0.25)
      settled_tick = -1;
    else if (settled_tick < 0)
      settled_tick = now.index;
    if (phase != previous_phase && switch_tick < 0) {
      switch_tick = now.index;
      y_at_switch = y;
    } else if (switch_tick < 0) {
      y_before_switch = y;
    }
    previous_phase = phase;
  }
  ASSERT_GE(switch_tick, 0) << "never switched to admittance";
  // The switch is taken in the update that makes y cross the threshold: y <= 4 N before it,
  // > 4 N with it.
  EXPECT_LE(y_before_switch, o.force_threshold);
  EXPECT_GT(y_at_switch, o.force_threshold);
  EXPECT_EQ(bench.Phase(), 1.0);

  // Settled (12 s): the normal force MuJoCo's contacts put on the fingertip.
  const double contact = bench.ContactForce();
  const double estimate = bench.Filtered();
  EXPECT_NEAR(contact, 5.0, 1.0) << "thesis: a 5 N grip";
  EXPECT_NEAR(estimate, 5.0, 0.05) << "the admittance regulates its estimate to f*";
  // The estimate neglects friction (§3.2.4.3): they agree within the joint's friction loss
  // at the lever arm.
  EXPECT_NEAR(estimate, contact, kFrictionLoss / kLever);
  RecordProperty("contact_force_N", std::to_string(contact));
  RecordProperty("estimate_N", std::to_string(estimate));
  RecordProperty("switch_s", std::to_string(switch_tick * 1e-3));
  std::printf(
      "contact %.3f N, estimate %.3f N, switch at %.3f s (y %.3f N), q %.4f rad, peak contact "
      "%.2f N, within 5 +- 0.25 N from %.3f s\n",
      contact, estimate, switch_tick * 1e-3, y_at_switch, bench.JointPosition(), peak_contact,
      settled_tick * 1e-3);
}

TEST(GripperAdmittanceTest, WithoutObjectClosesToTheLimitAndReportsNoContact) {
  Bench bench(/*with_block=*/false);
  double max_y = 0.0, y_moving = 0.0, v_previous = 0.0, max_dv = 0.0;
  while (bench.tick.index < 12000) {
    const graph::Tick now = bench.tick;
    bench.Step();
    const double v = bench.velocity->value()[0];
    max_dv = std::max(max_dv, std::abs(v - v_previous));
    v_previous = v;
    max_y = std::max(max_y, bench.Filtered());
    if (now.index == 5000) y_moving = bench.Filtered();  // mid-way, the ramp at full speed
    ASSERT_EQ(bench.Phase(), 0.0) << "switched without contact at " << now.index;
  }
  EXPECT_NEAR(bench.JointPosition(), kClosed, 2e-3);
  const graph::Tick last{bench.tick.index - 1, 0.0, 1e-3};
  EXPECT_NEAR(bench.feature->measured_position_output().Eval(last), bench.JointPosition(), 1e-3);
  // Moving freely at the ramp speed the servo only fights the joint's damping and friction loss:
  // f̂ = (b q̇ + τ_fl) / d = (1 · 0.1 + 0.1) / 0.1 = 2 N — what the threshold must stay above.
  EXPECT_NEAR(y_moving, 2.0, 0.1);
  // The ramp never steps the command (the controller's start check refuses a jump): at most
  // acceleration · dt per tick, from rest (+5 %: the solver's 50 ms switch blend lags the ramp a
  // little at the start, and the task's λ e takes the lag back).
  EXPECT_LE(max_dv, 1.05 * bench.feature->options().acceleration * 1e-3);
  EXPECT_EQ(bench.ContactForce(), 0.0);
  EXPECT_LT(max_y, bench.feature->options().force_threshold);
  std::printf(
      "free closing: largest force estimate %.3f N (damping and friction at the ramp speed)\n",
      max_y);
}

TEST(GripperAdmittanceTest, ReleaseGoesThroughAdmittanceThenOpens) {
  Bench bench(/*with_block=*/true);
  while (bench.tick.index < 10000) bench.Step();
  ASSERT_EQ(bench.Phase(), 1.0);
  bench.feature->release_input().SetValue(true);
  bench.feature->position_target_input().SetValue(kOpen);
  bool saw_releasing = false;
  while (bench.tick.index < 22000) {
    bench.Step();
    const double phase = bench.Phase();
    if (phase == 2.0) saw_releasing = true;
    if (phase == 3.0) {
      ASSERT_TRUE(saw_releasing) << "opened before releasing the force";
    }
  }
  EXPECT_TRUE(saw_releasing);
  EXPECT_EQ(bench.Phase(), 3.0);
  EXPECT_NEAR(bench.JointPosition(), kOpen, 2e-3);
  EXPECT_EQ(bench.ContactForce(), 0.0);
}

TEST(GripperAdmittanceTest, ReleasingControllerStartsWithoutACommandStep) {
  // A controller switch refuses a command that jumps by more than 0.1 rad/s: a releasing task
  // that stepped its force target from 5 N to 0 N stepped the command by K_a f* = 0.1 rad/s.
  // The target ramps from the force held instead, so the command moves by little per tick.
  Bench bench(/*with_block=*/true);
  while (bench.tick.index < 10000) bench.Step();
  ASSERT_EQ(bench.Phase(), 1.0);
  double before = bench.command;
  bench.feature->release_input().SetValue(true);
  bench.feature->position_target_input().SetValue(kOpen);
  double largest_step = 0.0;
  while (bench.tick.index < 11000) {
    bench.Step();
    const double v = bench.command;
    largest_step = std::max(largest_step, std::abs(v - before));
    before = v;
  }
  EXPECT_LT(largest_step, 0.01) << "rad/s between two ticks";
  EXPECT_NE(bench.Phase(), 1.0);
}

TEST(GripperAdmittanceTest, AControllerSwitchedInWhileTheFingersCloseGoesOnClosing) {
  // Fingers still short of the object (or the kinematic backend, where nothing stops them) when
  // the next controller is switched in: its closing task's ramp used to start at rest, a command
  // step of the ramp's speed (0.1 rad/s, exactly the switch's jump bound, which refused it). It
  // starts at the speed the joint was commanded the tick before instead.
  Bench bench(/*with_block=*/false);
  while (bench.tick.index < 3000) bench.Step();
  const double speed = bench.feature->options().speed;
  const double closing = bench.command;  // the applied command of the last tick
  ASSERT_NEAR(closing, -speed, 1e-6) << "the ramp at full speed";
  const Eigen::VectorXd q = bench.feature->kinematics_input().Eval(bench.tick).q();
  for (const bool told : {false, true}) {
    graph::GraphBuilder b;
    auto& robot = b.Add<RobotModel>("robot", bench.model);
    auto& next = b.Add<FeatureGripperAdmittance>("next", bench.model, "gripper_right_joint",
                                                 kClosed, false, GripperAdmittanceOptions{});
    b.Connect(robot.kinematics_output(), next.kinematics_input());
    robot.configuration_input().SetValue(q);
    next.effort_input().SetValue(Eigen::VectorXd::Zero(1));
    if (told) next.applied_velocity_input().SetValue(Eigen::VectorXd::Constant(1, closing));
    auto graph = b.Build();
    const graph::Tick first{0, 0.0, 1e-3};  // pulled, not committed: the state is the initial
    const FeatureTerms& terms = next.terms_output().Eval(first);
    const double ramp_rate = -terms.drift[0];  // the task's command v = ṙ − λ e, e = 0 here
    EXPECT_EQ(terms.error[0], 0.0);
    const double acceleration_step = next.options().acceleration * 1e-3;
    if (told) {
      EXPECT_NEAR(ramp_rate, closing, acceleration_step + 1e-12);
    } else {  // from rest: the step the switch refused
      EXPECT_NEAR(ramp_rate, -acceleration_step, 1e-12);
      EXPECT_GT(std::abs(ramp_rate - closing), 0.99 * speed);
    }
  }
}

TEST(GripperAdmittanceTest, ReleaseAfterHoldsTheGripThatLongFirst) {
  // A hand-over: the releasing gripper keeps squeezing until `release_after` seconds of its task
  // have passed (the other gripper closes meanwhile), then releases as above.
  GripperAdmittanceOptions options;
  options.release_after = 12.0;
  Bench bench(/*with_block=*/true, options);
  while (bench.tick.index < 10000) bench.Step();
  ASSERT_EQ(bench.Phase(), 1.0);
  bench.feature->release_input().SetValue(true);
  bench.feature->position_target_input().SetValue(kOpen);
  while (bench.tick.index < 11990) {
    bench.Step();
    ASSERT_EQ(bench.Phase(), 1.0) << "released at tick " << bench.tick.index << " before 12 s";
  }
  EXPECT_NEAR(bench.ContactForce(), options.force_target, 1.0) << "still squeezing at 12 s";
  bool saw_releasing = false;
  while (bench.tick.index < 24000) {
    bench.Step();
    if (bench.Phase() == 2.0) saw_releasing = true;
  }
  EXPECT_TRUE(saw_releasing);
  EXPECT_EQ(bench.Phase(), 3.0);
  EXPECT_NEAR(bench.JointPosition(), kOpen, 2e-3);
}

TEST(GripperAdmittanceTest, AReleasingTaskThatWaitsStartsByHolding) {
  // Its first phase is holding (what the previous controller held), not releasing.
  const ModelPtr model = BenchModel();
  GripperAdmittanceOptions o;
  o.release_after = 1.0;
  FeatureGripperAdmittance waits("g", model, "gripper_right_joint", kOpen, true, o);
  EXPECT_EQ(waits.phase_output().Eval(graph::Tick{}), 1.0);
  FeatureGripperAdmittance now("g", model, "gripper_right_joint", kOpen, true, {});
  EXPECT_EQ(now.phase_output().Eval(graph::Tick{}), 2.0);
}

TEST(GripperAdmittanceTest, AReleasingTaskThatWaitsHoldsTheForceItFinds) {
  // A hand-over's releasing gripper first holds what the previous controller held. With nothing
  // squeezed (fingers at their limit, closed on nothing: the dry run's kinematic backend, no
  // effort) its first command is the previous one, 0; holding f* commanded K_a f* = 0.1 rad/s,
  // which the switch refused. Squeezing 5 N it holds 5 N, as before.
  const ModelPtr model = BenchModel();
  GripperAdmittanceOptions o;
  o.release_after = 1.0;
  for (const double effort : {0.0, 5.0}) {  // f̂ = s k_τ effort / d: 0 N, then 50 N clamped to f*
    graph::GraphBuilder b;
    auto& robot = b.Add<RobotModel>("robot", model);
    auto& waits =
        b.Add<FeatureGripperAdmittance>("waits", model, "gripper_right_joint", kOpen, true, o);
    b.Connect(robot.kinematics_output(), waits.kinematics_input());
    robot.configuration_input().SetValue(Eigen::VectorXd::Constant(1, kClosed));
    waits.effort_input().SetValue(Eigen::VectorXd::Constant(1, -effort));  // s = -1: squeezing
    auto graph = b.Build();
    const graph::Tick first{0, 0.0, 1e-3};
    ASSERT_EQ(waits.phase_output().Eval(first), 1.0);
    const double y = waits.force_filtered_output().Eval(first);
    const double command = -o.task_gain * waits.terms_output().Eval(first).error[0];
    if (effort == 0.0) {
      EXPECT_EQ(y, 0.0);
      EXPECT_EQ(command, 0.0) << "nothing held, nothing commanded";
    } else {
      EXPECT_GT(y, o.force_target);
      // Holding f* (clamped): the command closes on by K_a (f* - y), as any holding task.
      EXPECT_NEAR(command, o.closing_direction * o.admittance_gain * (o.force_target - y), 1e-12);
    }
  }
}

TEST(GripperAdmittanceTest, RejectsBadOptionsWithTheirNames) {
  const ModelPtr model = BenchModel();
  GripperAdmittanceOptions o;
  o.force_threshold = 6.0;
  try {
    FeatureGripperAdmittance f("g", model, "gripper_right_joint", kClosed, false, o);
    FAIL() << "accepted a threshold above the target";
  } catch (const SotError& e) {
    EXPECT_NE(std::string(e.what()).find("force_threshold (6.000000 N) must be below force_target"),
              std::string::npos)
        << e.what();
  }
  o = {};
  o.closing_direction = 0.5;
  EXPECT_THROW(FeatureGripperAdmittance("g", model, "gripper_right_joint", kClosed, false, o),
               SotError);
  EXPECT_THROW(FeatureGripperAdmittance("g", model, "no_such_joint", kClosed, false, {}), SotError);
  o = {};
  o.release_after = -1.0;
  EXPECT_THROW(FeatureGripperAdmittance("g", model, "gripper_right_joint", kOpen, true, o),
               SotError);
}

}  // namespace
}  // namespace marionette::sot
