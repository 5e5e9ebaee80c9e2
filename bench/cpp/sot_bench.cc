// Per-tick cost of the TALOS reference stack (tests/cpp/sot/talos_stack.h):
//   [joint limits] > [left foot 6D, right foot 6D, CoM 3D] > [right gripper 6D, left gripper
//   relative to right 6D] > [posture 32D]
// in closed loop with the kinematic device at 1 kHz, from half-sitting, reaching 15 cm.
// Every tick is timed (steady_clock) and split into: kinematics (RobotModel, one Pinocchio
// pass), tasks (7 features + 7 tasks), solve (the Solver entity) and the rest of the graph
// (device update, states); solve_path = kinematics + tasks + solve of the same tick (what the
// peers of bench/sot are compared with). Prints one JSON object: medians, p90, p99 and max in µs
// per phase, for the nominal run, the same stack without joint limits and a run whose reach is
// out of range (bounds bind: QP levels), with the model files and each run's reach (the peers
// rebuild the same stack from them), the final right-gripper position error and the largest
// foot task error seen (the peers report the same, to show they solve the same problem).
//
//   marionette-bench-sot [--ticks N]    (N >= 10000, default 20000)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "talos_stack.h"

namespace {

using Clock = std::chrono::steady_clock;
using marionette::graph::Tick;
namespace sot = marionette::sot;

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

// Runs `ticks` instrumented ticks after a warm-up; returns the JSON of one scenario.
std::string Run(const char* scenario, const sot::testing::TalosStackOptions& options, int ticks) {
  sot::testing::TalosStack s = sot::testing::BuildTalosStack(options);
  std::vector<sot::Task*> tasks{s.left_foot,  s.right_foot, s.com,
                                s.right_hand, s.left_hand,  s.posture};
  if (s.limits) tasks.push_back(s.limits);
  Tick tick;
  marionette::graph::RunTicks(*s.graph, &tick, 500);  // warm-up (start-up blend, caches)
  std::vector<double> kinematics, task_terms, solve, solve_path, rest, whole;
  int qp_ticks = 0;
  double max_foot_error = 0.0;
  for (int i = 0; i < ticks; ++i, ++tick) {
    const auto t0 = Clock::now();
    s.robot->kinematics_output().Eval(tick);
    const auto t1 = Clock::now();
    for (sot::Task* task : tasks) task->terms_output().Eval(tick);
    const auto t2 = Clock::now();
    s.solver->velocity_output().Eval(tick);
    const auto t3 = Clock::now();
    s.graph->Evaluate(tick);  // everything else: device update, solver states
    const auto t4 = Clock::now();
    kinematics.push_back(Us(t0, t1));
    task_terms.push_back(Us(t1, t2));
    solve.push_back(Us(t2, t3));
    solve_path.push_back(Us(t0, t3));
    rest.push_back(Us(t3, t4));
    whole.push_back(Us(t0, t4));
    qp_ticks += s.solver->report().num_qp > 0;
    max_foot_error = std::max({max_foot_error, s.left_foot->error_norm_output().Eval(tick),
                               s.right_foot->error_norm_output().Eval(tick)});
  }
  // The same ticks uninstrumented: graph.Evaluate alone.
  std::vector<double> plain;
  for (int i = 0; i < ticks; ++i, ++tick) {
    const auto t0 = Clock::now();
    s.graph->Evaluate(tick);
    plain.push_back(Us(t0, Clock::now()));
  }
  const Eigen::Vector3d target = s.right_hand_feature->reference_input().Eval(tick).translation();
  const sot::Kinematics& k = s.robot->kinematics_output().Eval(tick);
  const double hand_error =
      (k.placement(sot::MakeFrameRef(*s.model, sot::testing::kRightGripper, "bench"))
           .translation() -
       target)
          .norm();
  char figures[300];
  std::snprintf(figures, sizeof figures,
                "\"reach\": [%.17g, %.17g, %.17g], \"joint_limits\": %s, "
                "\"final_hand_position_error\": %.6g, \"max_foot_error\": %.6g, ",
                options.reach.x(), options.reach.y(), options.reach.z(),
                options.joint_limits ? "true" : "false", hand_error, max_foot_error);
  std::string out = std::string("\"") + scenario + "\": {\"ticks\": " + std::to_string(ticks) +
                    ", \"qp_ticks\": " + std::to_string(qp_ticks) + ", " + figures;
  out += Json("kinematics", Summarize(kinematics)) + ", ";
  out += Json("tasks", Summarize(task_terms)) + ", ";
  out += Json("solve", Summarize(solve)) + ", ";
  out += Json("solve_path", Summarize(solve_path)) + ", ";
  out += Json("graph_rest", Summarize(rest)) + ", ";
  out += Json("tick", Summarize(whole)) + ", ";
  out += Json("tick_uninstrumented", Summarize(plain)) + "}";
  return out;
}

}  // namespace

constexpr const char* kUsage =
    "usage: marionette-bench-sot [--ticks N]\n"
    "Times the TALOS reference stack in closed loop at 1 kHz (N ticks per run, N >= 10000,\n"
    "default 20000) and prints one JSON object (medians, p90, p99, max in us per phase).\n"
    "Run it through scripts/bench sot, which puts TSID and pink in the same run.\n";

int main(int argc, char** argv) {
  int ticks = 20000;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--help") == 0 || std::strcmp(argv[i], "-h") == 0) {
      std::fputs(kUsage, stdout);
      return 0;
    }
    if (std::strcmp(argv[i], "--ticks") == 0 && i + 1 < argc) {
      char* end = nullptr;
      const long value = std::strtol(argv[++i], &end, 10);
      if (*end != '\0') {
        std::fprintf(stderr, "--ticks takes a whole number of ticks (got '%s')\n", argv[i]);
        return 2;
      }
      ticks = static_cast<int>(std::min(value, 100000000L));
      continue;
    }
    std::fprintf(stderr, "unknown argument '%s'\n%s", argv[i], kUsage);
    return 2;
  }
  if (ticks < 10000) {
    std::fprintf(stderr, "--ticks must be >= 10000 (got %d)\n", ticks);
    return 2;
  }
  sot::testing::TalosStackOptions nominal;
  sot::testing::TalosStackOptions saturated;
  saturated.reach = Eigen::Vector3d(0.6, -0.4, 0.5);  // out of reach: bounds bind, QP levels
  saturated.relative_hand = true;
  sot::testing::TalosStackOptions equality_only;
  equality_only.joint_limits = false;
  const std::string data = sot::ExampleRobotDataDir() + "/talos_data/";
  std::printf("{\"model\": {\"urdf\": \"%s\", \"srdf\": \"%s\"},\n %s,\n %s,\n %s}\n",
              (data + "robots/talos_reduced.urdf").c_str(), (data + "srdf/talos.srdf").c_str(),
              Run("nominal", nominal, ticks).c_str(),
              Run("equality_only", equality_only, ticks).c_str(),
              Run("bounds_binding", saturated, ticks).c_str());
  return 0;
}
