// The boundary's cost per message (bench/boundary): wire::Validate on each input type of the
// controller, next to lcm-gen's own decode of the same bytes (the work it guards), and the
// signature check (HMAC-SHA256 + sequence) by message size.
#include <benchmark/benchmark.h>

#include <string>
#include <vector>

#include "marionette/lcm/signing.h"
#include "marionette/lcm/validate.h"
#include "marionette/lcmt_command.hpp"
#include "marionette/lcmt_controller_spec.hpp"
#include "marionette/lcmt_dg_request.hpp"
#include "marionette/lcmt_footstep_plan.hpp"
#include "marionette/lcmt_sim_command.hpp"
#include "marionette/lcmt_task_reference.hpp"

namespace marionette::wire {
namespace {

template <typename Msg>
std::vector<uint8_t> Encode(const Msg& msg) {
  std::vector<uint8_t> b(msg.getEncodedSize());
  msg.encode(b.data(), 0, static_cast<int>(b.size()));
  return b;
}

// A streamer's chunk: 200 samples of an SE3 reference (7 values, 6 derivatives).
lcmt_task_reference Chunk() {
  lcmt_task_reference r{};
  r.utime = 1'000'000;
  r.task_name = "right_gripper";
  r.controller_id = 12345;
  r.dt_us = 1000;
  r.num_samples = 200;
  r.value_size = 7;
  r.derivative_size = 6;
  r.value.assign(200, {0.4, -0.2, 0.9, 1.0, 0.0, 0.0, 0.0});
  r.derivative.assign(200, std::vector<double>(6, 0.01));
  r.sequence = 3;
  return r;
}

// A TALOS transition's spec: feet, CoM, two grippers, waist, head, admittance, posture.
lcmt_controller_spec TalosSpec() {
  lcmt_controller_spec s{};
  s.controller_id = 12345;
  s.name = "talos/left_gripper > plank/H1 | f_01";
  s.max_switch_velocity_jump = 0.1;
  s.reference_timeout = 0.1;
  for (int i = 0; i < 9; ++i) {
    lcmt_task_spec t{};
    t.name = "task_" + std::to_string(i);
    t.kind = i < 6 ? "se3" : "posture";
    t.priority = i / 3;
    t.frame = "gripper_left_base_link";
    t.gain = 10.0;
    t.reference_channel = i % 2 ? "TASK_REFERENCE" : "";
    if (i < 6) {
      t.num_reference = 7;
      t.reference = {0.1, 0.2, 0.8, 1.0, 0.0, 0.0, 0.0};
    } else {
      t.num_joints = 14;
      t.joint_name.assign(14, "arm_left_4_joint");
    }
    s.tasks.push_back(t);
  }
  s.num_tasks = static_cast<int32_t>(s.tasks.size());
  return s;
}

lcmt_command Command() {
  lcmt_command c{};
  c.utime = 1;
  c.command = "heartbeat";
  c.source = "marionette:4242";
  return c;
}

lcmt_dg_request Request() {
  lcmt_dg_request r{};
  r.request_id = 1;
  r.client = "host:4242:7f00";
  r.command = "set";
  r.num_signals = 1;
  r.signal = {"c3_posture.gain"};
  r.num_values = 1;
  r.value = {2.5};
  return r;
}

lcmt_footstep_plan Plan() {
  lcmt_footstep_plan p{};
  p.plan_id = 1;
  for (int k = 0; k < 16; ++k) {
    lcmt_footstep s{};
    s.index = k;
    s.is_left = k % 2 == 0;
    s.x = 0.1 * k;
    s.duration = 0.8;
    s.double_support = 0.1;
    s.step_height = 0.05;
    p.steps.push_back(s);
  }
  p.num_steps = 16;
  return p;
}

lcmt_sim_command SimCommand() {
  lcmt_sim_command c{};
  c.command = "set_object_pose";
  c.object_name = "plank";
  c.quaternion[0] = 1.0;
  return c;
}

template <typename Msg>
void BM_Validate(benchmark::State& state, Msg msg) {
  const std::vector<uint8_t> b = Encode(msg);
  for (auto _ : state) {
    const Verdict v = Validate<Msg>(b.data(), b.size(), int64_t{1'000'000});
    benchmark::DoNotOptimize(v.refusal);
  }
  state.counters["bytes"] = static_cast<double>(b.size());
}

template <typename Msg>
void BM_Decode(benchmark::State& state, Msg msg) {
  const std::vector<uint8_t> b = Encode(msg);
  for (auto _ : state) {
    Msg out;
    benchmark::DoNotOptimize(out.decode(b.data(), 0, static_cast<int>(b.size())));
  }
  state.counters["bytes"] = static_cast<double>(b.size());
}

BENCHMARK_CAPTURE(BM_Validate, reference_chunk, Chunk());
BENCHMARK_CAPTURE(BM_Decode, reference_chunk, Chunk());
BENCHMARK_CAPTURE(BM_Validate, talos_spec, TalosSpec());
BENCHMARK_CAPTURE(BM_Decode, talos_spec, TalosSpec());
BENCHMARK_CAPTURE(BM_Validate, command, Command());
BENCHMARK_CAPTURE(BM_Decode, command, Command());
BENCHMARK_CAPTURE(BM_Validate, dg_request, Request());
BENCHMARK_CAPTURE(BM_Decode, dg_request, Request());
BENCHMARK_CAPTURE(BM_Validate, footstep_plan, Plan());
BENCHMARK_CAPTURE(BM_Decode, footstep_plan, Plan());
BENCHMARK_CAPTURE(BM_Validate, sim_command, SimCommand());
BENCHMARK_CAPTURE(BM_Decode, sim_command, SimCommand());

// Verifier::Verify on pre-signed messages of state.range(0) bytes (a fresh verifier per pass
// over them: every one is new to it).
void BM_Verify(benchmark::State& state) {
  const std::string key(32, 'k');
  const std::string message(static_cast<size_t>(state.range(0)), 'm');
  Signer signer(key);
  std::vector<std::string> signed_messages;
  for (int i = 0; i < 4096; ++i)
    signed_messages.push_back(signer.Sign("TASK_REFERENCE", message.data(), message.size(), 1));
  auto verifier = std::make_unique<Verifier>(key, 1e12);
  size_t i = 0, size = 0;
  std::string detail;
  for (auto _ : state) {
    if (i == signed_messages.size()) {
      state.PauseTiming();
      verifier = std::make_unique<Verifier>(key, 1e12);
      i = 0;
      state.ResumeTiming();
    }
    const std::string& m = signed_messages[i++];
    if (verifier->Verify("TASK_REFERENCE", m.data(), m.size(), 1, &size, &detail) !=
        SignatureCheck::kAccepted) {
      state.SkipWithError("a signed message was refused");
      break;
    }
  }
}
BENCHMARK(BM_Verify)->Arg(64)->Arg(1024)->Arg(20912);

}  // namespace
}  // namespace marionette::wire

BENCHMARK_MAIN();
