// TSID 1.10 (C++ API) on the TALOS reference stack of bench/sot, in closed loop at 1 kHz.
//
// TSID is an inverse-dynamics library: it has no velocity-level (IK) formulation. Its closest
// faithful equivalent is used (bench/README.md, "sot"): the robot is wrapped as a fully actuated
// system (RobotWrapper(model, FIXED_BASE_SYSTEM) on the free-flyer model, so na = nv = 38 and no
// under-actuated base-dynamics row), TSID's "acceleration" variable dv is read as the joint
// velocity v, and TSID is always given v = 0, so every task's drift J̇v and damping Kd terms
// vanish and its rows are exactly  J dv = Kp e  — the velocity-level task  J v = -λ e  of our
// stack (TSID's error sign is reversed: Kp = λ). The same model files, tasks, gains and
// closed-loop integration q ← q ⊕ v dt as marionette-bench-sot:
//   priority 0 (hard):  joint bounds (TaskJointBounds: per-tick box λ_l(q_min - q) <= v <=
//                       λ_l(q_max - q), |v| <= v_max, λ_l = 500/s), left foot 6D, right foot
//                       6D, CoM 3D (Kp 10)
//   priority 1 (cost):  right gripper 6D (Kp 1, weight 1), left gripper relative to right 6D
//                       (TaskTwoFramesEquality onto a frame fixed to the right gripper at the
//                       initial relative pose; Kp 1, weight 1), posture 32D (Kp 1, weight
//                       --posture-weight, default 1e-5)
// TSID's two priorities cannot express our three equality levels: the grippers over the
// posture is a weight ratio, not a strict priority. With 1e-3 (TSID's examples) the posture
// holds the right gripper 1 cm short of its target at steady state, with 1e-5 0.4 mm: 1e-5 is
// the closer to the strict hierarchy; the QP's cost barely depends on it.
//
// Per tick, what TSID needs and what is timed: the joint-bound box update (6 flops per joint),
// computeProblemData (Pinocchio computeAllTerms — kinematics AND the dynamics terms M, h that
// TSID always computes — plus every task) and the QP (eiquadprog-fast, TSID's default). The
// integration is not timed. Kinematics alone (computeAllTerms) is timed in a second pass over the
// recorded configurations, for the split.
//
//   marionette-bench-sot-tsid --urdf U --srdf S [--ticks N] [--reach x y z] [--scenario NAME]
// prints one JSON object {"<scenario>": {...}}.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/parsers/srdf.hpp>
#include <pinocchio/parsers/urdf.hpp>
#include <tsid/formulations/inverse-dynamics-formulation-acc-force.hpp>
#include <tsid/robots/robot-wrapper.hpp>
#include <tsid/solvers/solver-HQP-factory.hpp>
#include <tsid/tasks/task-com-equality.hpp>
#include <tsid/tasks/task-joint-bounds.hpp>
#include <tsid/tasks/task-joint-posture.hpp>
#include <tsid/tasks/task-se3-equality.hpp>
#include <tsid/tasks/task-two-frames-equality.hpp>

namespace {

using Clock = std::chrono::steady_clock;
using Vector = Eigen::VectorXd;

constexpr double kDt = 1e-3;          // the 1 kHz tick of marionette-bench-sot
constexpr double kLimitGain = 500.0;  // marionette JointLimitsOptions::position_gain
constexpr double kNoLimit = 1e10;     // "no limit" in URDF parsers and in TSID
constexpr const char* kRightGripper = "gripper_right_base_link";
constexpr const char* kLeftGripper = "gripper_left_base_link";
constexpr const char* kLeftTarget = "bench_left_gripper_target";

struct Quantiles {
  double median, p90, p99, max;
};

Quantiles Summarize(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  auto at = [&](double q) { return v[static_cast<size_t>(q * (v.size() - 1))]; };
  return {at(0.5), at(0.9), at(0.99), v.back()};
}

double Us(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

std::string Json(const char* name, const Quantiles& q) {
  char buffer[200];
  std::snprintf(buffer, sizeof buffer,
                "\"%s\": {\"median\": %.3f, \"p90\": %.3f, \"p99\": %.3f, \"max\": %.3f}", name,
                q.median, q.p90, q.p99, q.max);
  return buffer;
}

[[noreturn]] void Fail(const std::string& message) {
  std::fprintf(stderr, "marionette-bench-sot-tsid: %s\n", message.c_str());
  std::exit(2);
}

struct Args {
  std::string urdf, srdf, scenario = "nominal";
  int ticks = 20000;
  double posture_weight = 1e-5;
  Eigen::Vector3d reach{0.10, -0.05, 0.10};
};

Args Parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto need = [&](int n) {
      if (i + n >= argc) Fail(k + " needs " + std::to_string(n) + " value(s)");
    };
    if (k == "--urdf") {
      need(1);
      a.urdf = argv[++i];
    } else if (k == "--srdf") {
      need(1);
      a.srdf = argv[++i];
    } else if (k == "--scenario") {
      need(1);
      a.scenario = argv[++i];
    } else if (k == "--ticks") {
      need(1);
      a.ticks = std::atoi(argv[++i]);
    } else if (k == "--posture-weight") {
      need(1);
      a.posture_weight = std::atof(argv[++i]);
    } else if (k == "--reach") {
      need(3);
      for (int j = 0; j < 3; ++j) a.reach[j] = std::atof(argv[++i]);
    } else {
      Fail("unknown argument '" + k +
           "' (expected --urdf --srdf --ticks --reach --scenario --posture-weight)");
    }
  }
  if (a.urdf.empty() || a.srdf.empty()) Fail("--urdf and --srdf are required");
  if (!(a.posture_weight > 0.0)) Fail("--posture-weight must be > 0");
  if (a.ticks < 10000) Fail("--ticks must be >= 10000 (got " + std::to_string(a.ticks) + ")");
  return a;
}

}  // namespace

int main(int argc, char** argv) {
  const Args args = Parse(argc, argv);
  pinocchio::Model model;
  pinocchio::urdf::buildModel(args.urdf, pinocchio::JointModelFreeFlyer(), model);
  pinocchio::srdf::loadReferenceConfigurations(model, args.srdf, false);
  const Vector q0 = model.referenceConfigurations.at("half_sitting");
  const int nv = model.nv;

  // The left gripper is held relative to the right one at its initial relative pose: TSID's
  // two-frame task makes two frames coincide, so that pose becomes a frame on the right gripper.
  {
    pinocchio::Data d(model);
    pinocchio::framesForwardKinematics(model, d, q0);
    const auto r = model.getFrameId(kRightGripper), l = model.getFrameId(kLeftGripper);
    const pinocchio::SE3 X_RL = d.oMf[r].actInv(d.oMf[l]);
    const auto& fr = model.frames[r];
    model.addFrame(
        pinocchio::Frame(kLeftTarget, fr.parentJoint, r, fr.placement * X_RL, pinocchio::OP_FRAME));
  }

  tsid::robots::RobotWrapper robot(model, tsid::robots::RobotWrapper::FIXED_BASE_SYSTEM);
  if (robot.na() != nv) Fail("expected a fully actuated wrapper");
  tsid::InverseDynamicsFormulationAccForce ik("tsid", robot);
  const Vector zero_v = Vector::Zero(nv);
  ik.computeProblemData(0.0, q0, zero_v);
  const pinocchio::Data& data = ik.data();
  auto pose = [&](const char* frame) { return data.oMf[model.getFrameId(frame)]; };

  tsid::tasks::TaskJointBounds bounds("limits", robot, kDt);
  // Position-limited 1-DoF joints (all 32 of TALOS) get the box; the free flyer none.
  std::vector<int> limited_v, limited_q;
  Vector v_max(nv);
  for (pinocchio::JointIndex j = 1; j < model.joints.size(); ++j) {
    if (model.nvs[j] != 1 || model.nqs[j] != 1) continue;
    const int iq = model.idx_qs[j], iv = model.idx_vs[j];
    if (model.lowerPositionLimit[iq] <= -kNoLimit || model.upperPositionLimit[iq] >= kNoLimit)
      continue;
    limited_q.push_back(iq);
    limited_v.push_back(iv);
    v_max[iv] = std::abs(model.upperVelocityLimit[iv]);
  }
  Vector lower = Vector::Constant(nv, -kNoLimit), upper = Vector::Constant(nv, kNoLimit);
  auto update_bounds = [&](const Vector& q) {
    for (size_t i = 0; i < limited_v.size(); ++i) {
      const int iq = limited_q[i], iv = limited_v[i];
      double lo = std::max(kLimitGain * (model.lowerPositionLimit[iq] - q[iq]), -v_max[iv]);
      double hi = std::min(kLimitGain * (model.upperPositionLimit[iq] - q[iq]), v_max[iv]);
      if (lo > hi) lo = hi = (lo > v_max[iv]) ? v_max[iv] : -v_max[iv];
      lower[iv] = lo;
      upper[iv] = hi;
    }
    bounds.setAccelerationBounds(lower, upper);
  };
  update_bounds(q0);

  auto se3_task = [&](const char* name, const char* frame, double kp) {
    auto t = std::make_unique<tsid::tasks::TaskSE3Equality>(name, robot, frame);
    t->Kp(kp * Vector::Ones(6));
    t->Kd(Vector::Zero(6));
    return t;
  };
  auto left_foot = se3_task("left_foot", "left_sole_link", 10.0);
  left_foot->setReference(pose("left_sole_link"));
  auto right_foot = se3_task("right_foot", "right_sole_link", 10.0);
  right_foot->setReference(pose("right_sole_link"));
  tsid::tasks::TaskComEquality com("com", robot);
  com.Kp(10.0 * Vector::Ones(3));
  com.Kd(Vector::Zero(3));
  tsid::trajectories::TrajectorySample com_ref(3);
  com_ref.setValue(robot.com(data));
  com.setReference(com_ref);
  auto right_hand = se3_task("right_hand", kRightGripper, 1.0);
  pinocchio::SE3 hand_target = pose(kRightGripper);
  hand_target.translation() += args.reach;
  right_hand->setReference(hand_target);
  tsid::tasks::TaskTwoFramesEquality left_hand("left_hand", robot, kLeftGripper, kLeftTarget);
  left_hand.Kp(1.0 * Vector::Ones(6));
  left_hand.Kd(Vector::Zero(6));
  tsid::tasks::TaskJointPosture posture("posture", robot);
  Vector mask = Vector::Ones(nv);
  mask.head(6).setZero();  // the 32 joints, not the free flyer (our posture is 32D)
  posture.setMask(mask);
  posture.Kp(1.0 * Vector::Ones(nv));
  posture.Kd(Vector::Zero(nv));
  tsid::trajectories::TrajectorySample posture_ref(robot.nq_actuated(), nv);
  posture_ref.setValue(q0.tail(robot.nq_actuated()));
  posture.setReference(posture_ref);

  ik.addMotionTask(bounds, 1.0, 0);
  ik.addMotionTask(*left_foot, 1.0, 0);
  ik.addMotionTask(*right_foot, 1.0, 0);
  ik.addMotionTask(com, 1.0, 0);
  ik.addMotionTask(*right_hand, 1.0, 1);
  ik.addMotionTask(left_hand, 1.0, 1);
  ik.addMotionTask(posture, args.posture_weight, 1);

  std::unique_ptr<tsid::solvers::SolverHQPBase> solver(
      tsid::solvers::SolverHQPFactory::createNewSolver(tsid::solvers::SOLVER_HQP_EIQUADPROG_FAST,
                                                       "eiquadprog-fast"));
  solver->resize(ik.nVar(), ik.nEq(), ik.nIn());

  Vector q = q0, v(nv);
  int failures = 0;
  double max_foot_error = 0.0;
  // One tick: bounds at q, problem data, QP, then (untimed) q ← q ⊕ v dt.
  auto tick = [&](double t, double* t_bounds, double* t_data, double* t_solve) {
    const auto a = Clock::now();
    update_bounds(q);
    const auto b = Clock::now();
    const tsid::solvers::HQPData& hqp = ik.computeProblemData(t, q, zero_v);
    const auto c = Clock::now();
    const tsid::solvers::HQPOutput& sol = solver->solve(hqp);
    const auto d = Clock::now();
    if (sol.status != tsid::solvers::HQP_STATUS_OPTIMAL) ++failures;
    v = ik.getAccelerations(sol);
    if (t_bounds) {
      *t_bounds = Us(a, b);
      *t_data = Us(b, c);
      *t_solve = Us(c, d);
    }
    max_foot_error = std::max({max_foot_error, double(left_foot->position_error().norm()),
                               double(right_foot->position_error().norm())});
    q = pinocchio::integrate(model, q, v * kDt);
  };

  double time = 0.0;
  for (int i = 0; i < 500; ++i, time += kDt) tick(time, nullptr, nullptr, nullptr);  // warm-up
  failures = 0;
  max_foot_error = 0.0;
  std::vector<double> t_bounds(args.ticks), t_data(args.ticks), t_solve(args.ticks),
      t_tick(args.ticks);
  std::vector<Vector> visited;
  visited.reserve(args.ticks);
  for (int i = 0; i < args.ticks; ++i, time += kDt) {
    visited.push_back(q);
    tick(time, &t_bounds[i], &t_data[i], &t_solve[i]);
    t_tick[i] = t_bounds[i] + t_data[i] + t_solve[i];
  }
  // Kinematics alone: TSID's computeAllTerms at the same configurations (second pass).
  std::vector<double> t_kin(args.ticks);
  pinocchio::Data scratch(robot.model());
  for (int i = 0; i < args.ticks; ++i) {
    const auto a = Clock::now();
    robot.computeAllTerms(scratch, visited[i], zero_v);
    t_kin[i] = Us(a, Clock::now());
  }
  ik.computeProblemData(time, q, zero_v);
  const double hand_error = (pose(kRightGripper).translation() - hand_target.translation()).norm();

  std::printf(
      "{\"%s\": {\"ticks\": %d, \"qp\": \"eiquadprog-fast\", \"variables\": %d, "
      "\"equalities\": %d, \"inequalities\": %d, \"posture_weight\": %g, \"qp_failures\": %d, "
      "\"final_hand_position_error\": %.6g, \"max_foot_error\": %.6g, %s, %s, %s, %s, %s}}\n",
      args.scenario.c_str(), args.ticks, ik.nVar(), ik.nEq(), ik.nIn(), args.posture_weight,
      failures, hand_error, max_foot_error, Json("kinematics", Summarize(t_kin)).c_str(),
      Json("bounds", Summarize(t_bounds)).c_str(), Json("problem_data", Summarize(t_data)).c_str(),
      Json("solve", Summarize(t_solve)).c_str(), Json("tick", Summarize(t_tick)).c_str());
  return 0;
}
