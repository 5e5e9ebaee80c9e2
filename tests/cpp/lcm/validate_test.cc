// wire::Validate against lcm-gen's own encoder (the reference for what a valid message is): valid
// messages pass without allocating; every lie about a length, a string, a boolean, a range or the
// type is refused with its reason before anything is decoded; and whatever passes decodes with
// lcm-gen's decoder exactly to its end (random mutations, many seeds).
#include "marionette/lcm/validate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "allocation_counter.h"
#include "marionette/lcmt_command.hpp"
#include "marionette/lcmt_controller_spec.hpp"
#include "marionette/lcmt_dg_request.hpp"
#include "marionette/lcmt_footstep_plan.hpp"
#include "marionette/lcmt_robot_state.hpp"
#include "marionette/lcmt_sim_command.hpp"
#include "marionette/lcmt_task_reference.hpp"

namespace marionette::wire {
namespace {

using Bytes = std::vector<uint8_t>;

template <typename Msg>
Bytes Encode(const Msg& msg) {
  Bytes b(msg.getEncodedSize());
  EXPECT_EQ(msg.encode(b.data(), 0, static_cast<int>(b.size())), static_cast<int>(b.size()));
  return b;
}

void PutBigEndian(Bytes* b, size_t at, uint64_t v, int bytes) {
  for (int i = bytes - 1; i >= 0; --i, v >>= 8) (*b)[at + i] = static_cast<uint8_t>(v & 0xff);
}

template <typename Msg>
Verdict Check(const Bytes& b, std::optional<int64_t> now_us = std::nullopt) {
  return Validate<Msg>(b.data(), b.size(), now_us);
}

// utime 1 s, task "tool", 3 samples of 7 values and 6 derivatives.
lcmt_task_reference Reference() {
  lcmt_task_reference r{};  // lcm-gen's types are aggregates: {} zeroes them
  r.utime = 1'000'000;
  r.task_name = "tool";
  r.controller_id = 4;
  r.dt_us = 1000;
  r.num_samples = 3;
  r.value_size = 7;
  r.derivative_size = 6;
  r.value.assign(3, {0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0});
  r.derivative.assign(3, std::vector<double>(6, 0.01));
  r.last_chunk = false;
  r.sequence = 2;
  return r;
}
// Byte offsets in Reference()'s encoding: fingerprint 8, utime 8, "tool" 4 + 5.
constexpr size_t kTaskName = 16, kNumSamples = 41, kValueSize = 45;

lcmt_controller_spec Spec() {
  lcmt_controller_spec s{};
  s.utime = 5;
  s.controller_id = 7;
  s.name = "reach";
  s.max_switch_velocity_jump = 0.1;
  s.reference_timeout = 0.1;
  s.num_tasks = 2;
  s.tasks.resize(2);
  s.tasks[0].name = "tool";
  s.tasks[0].kind = "se3";
  s.tasks[0].frame = "tool0";
  s.tasks[0].gain = 2.0;
  s.tasks[0].num_reference = 7;
  s.tasks[0].reference = {0.5, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0};
  s.tasks[1].name = "posture";
  s.tasks[1].kind = "posture";
  s.tasks[1].priority = 1;
  s.tasks[1].num_joints = 1;
  s.tasks[1].joint_name = {"shoulder_pan_joint"};
  return s;
}

lcmt_dg_request Request() {
  lcmt_dg_request r{};
  r.utime = 1;
  r.request_id = 9;
  r.client = "";
  r.command = "set";
  r.num_signals = 0;
  r.num_values = 1;
  r.value = {2.0};
  r.rate = 0.0;
  return r;
}
// fingerprint 8, utime 8, request_id 8, "" 4 + 1, "set" 4 + 4, num_signals 4.
constexpr size_t kNumValues = 41;

lcmt_footstep_plan Plan() {
  lcmt_footstep_plan p{};
  p.plan_id = 1;
  p.num_steps = 2;
  p.steps.resize(2);
  for (int k = 0; k < 2; ++k) {
    p.steps[k].index = k;
    p.steps[k].is_left = k == 0;
    p.steps[k].x = 0.2 * k;
    p.steps[k].duration = 0.8;
    p.steps[k].double_support = 0.1;
    p.steps[k].step_height = 0.05;
    p.steps[k].num_via = 1;
    p.steps[k].via = {{0.1, 0.0, 0.1}};
  }
  return p;
}

TEST(ValidateTest, ValidMessagesPassWithoutAllocating) {
  const Bytes reference = Encode(Reference()), spec = Encode(Spec()), request = Encode(Request()),
              plan = Encode(Plan());
  testing::ScopedAllocationCounter counter;
  EXPECT_TRUE(Check<lcmt_task_reference>(reference, 1'500'000).ok());
  EXPECT_TRUE(Check<lcmt_controller_spec>(spec).ok());
  EXPECT_TRUE(Check<lcmt_dg_request>(request).ok());
  EXPECT_TRUE(Check<lcmt_footstep_plan>(plan).ok());
  EXPECT_EQ(counter.allocations(), 0);
}

template <typename Msg>
void EveryTruncationIsRefused(const Msg& msg) {
  const Bytes full = Encode(msg);
  for (size_t n = 0; n < full.size(); ++n) {
    const Verdict v = Check<Msg>(Bytes(full.begin(), full.begin() + n));
    ASSERT_FALSE(v.ok()) << n << " of " << full.size() << " bytes passed";
    EXPECT_EQ(v.refusal, n < 8 ? Refusal::kWrongType : Refusal::kPastTheEnd) << v.detail;
  }
}

TEST(ValidateTest, EveryTruncationIsRefused) {
  EveryTruncationIsRefused(Reference());
  EveryTruncationIsRefused(Spec());
  EveryTruncationIsRefused(Request());
  EveryTruncationIsRefused(Plan());
}

TEST(ValidateTest, LyingCountsAreRefusedByTheirBound) {
  const Bytes valid = Encode(Reference());
  struct Case {
    size_t at;
    int64_t value;
    Refusal refusal;
  };
  // num_samples and value_size: negative, over their @max (1000, 128), or more than the bytes.
  for (const Case& c :
       {Case{kNumSamples, -1, Refusal::kNegativeLength},
        Case{kNumSamples, std::numeric_limits<int32_t>::min(), Refusal::kNegativeLength},
        Case{kNumSamples, 1001, Refusal::kOverMaximum},
        Case{kNumSamples, 1 << 30, Refusal::kOverMaximum},
        Case{kNumSamples, std::numeric_limits<int32_t>::max(), Refusal::kOverMaximum},
        Case{kNumSamples, 1000, Refusal::kPastTheEnd}, Case{kNumSamples, 4, Refusal::kPastTheEnd},
        Case{kValueSize, -2, Refusal::kNegativeLength},
        Case{kValueSize, 129, Refusal::kOverMaximum},
        Case{kValueSize, 128, Refusal::kPastTheEnd}}) {
    Bytes b = valid;
    PutBigEndian(&b, c.at, static_cast<uint64_t>(c.value), 4);
    const Verdict v = Check<lcmt_task_reference>(b);
    EXPECT_EQ(v.refusal, c.refusal) << c.value << ": " << v.detail;
  }
  // Fewer samples than sent: the fields after the arrays read the wrong bytes (here a double's
  // first byte, 0x3f, as the boolean last_chunk).
  Bytes fewer = valid;
  PutBigEndian(&fewer, kNumSamples, 2, 4);
  EXPECT_EQ(Check<lcmt_task_reference>(fewer).refusal, Refusal::kNotBoolean)
      << Check<lcmt_task_reference>(fewer).detail;
}

TEST(ValidateTest, HugeCountInASmallRequestIsRefusedWithoutAllocatingIt) {
  // The DG_REQUEST that grew the controller to 1.2 GB: num_values = 2^27 in a few dozen bytes.
  Bytes b = Encode(Request());
  PutBigEndian(&b, kNumValues, uint64_t{1} << 27, 4);
  testing::ScopedAllocationCounter counter;
  const Verdict v = Check<lcmt_dg_request>(b);
  EXPECT_EQ(v.refusal, Refusal::kOverMaximum);
  EXPECT_EQ(v.detail, "num_values: 134217728 > 4096");
  EXPECT_LT(counter.allocations(), 8);  // the detail's strings only
}

TEST(ValidateTest, BadStringLengthsAreRefused) {
  const Bytes valid = Encode(Reference());
  for (const auto& [length, refusal] : std::vector<std::pair<int64_t, Refusal>>{
           {0, Refusal::kNegativeLength},
           {-1, Refusal::kNegativeLength},
           {std::numeric_limits<int32_t>::min(), Refusal::kNegativeLength},
           {1 << 30, Refusal::kPastTheEnd},
           {3, Refusal::kUnterminatedString}}) {
    Bytes b = valid;
    PutBigEndian(&b, kTaskName, static_cast<uint64_t>(length), 4);
    const Verdict v = Check<lcmt_task_reference>(b);
    EXPECT_EQ(v.refusal, refusal) << length << ": " << v.detail;
    EXPECT_EQ(v.detail.rfind("task_name", 0), 0u) << v.detail;
  }
  lcmt_task_reference long_name = Reference();
  long_name.task_name = std::string(129, 'x');  // @maxlen 128
  EXPECT_EQ(Check<lcmt_task_reference>(Encode(long_name)).refusal, Refusal::kOverMaximum);
}

TEST(ValidateTest, NumbersOutsideTheirRangeAreRefusedNamingTheField) {
  lcmt_controller_spec spec = Spec();
  spec.tasks[1].gain = 1e300;
  Verdict v = Check<lcmt_controller_spec>(Encode(spec));
  EXPECT_EQ(v.refusal, Refusal::kOutOfRange);
  EXPECT_EQ(v.detail, "tasks[1].gain: 1e+300 outside [0, 1000]");
  for (double bad : {std::nan(""), std::numeric_limits<double>::infinity(), -1e-9, 100.5}) {
    spec = Spec();
    spec.max_switch_velocity_jump = bad;
    EXPECT_EQ(Check<lcmt_controller_spec>(Encode(spec)).refusal, Refusal::kOutOfRange) << bad;
  }
  lcmt_task_reference r = Reference();
  r.value[2][6] = std::nan("");
  v = Check<lcmt_task_reference>(Encode(r), 1'000'000);
  EXPECT_EQ(v.refusal, Refusal::kOutOfRange);
  EXPECT_EQ(v.detail.rfind("value[2][6]: ", 0), 0u) << v.detail;
  r = Reference();
  r.dt_us = 0;
  EXPECT_EQ(Check<lcmt_task_reference>(Encode(r)).refusal, Refusal::kOutOfRange);
}

TEST(ValidateTest, TimeStampsAreCheckedAroundTheControllersClock) {
  lcmt_task_reference r = Reference();  // sample 0 at 1 s; accepted within [now - 10, now + 10] s
  for (const auto& [now_us, ok] : std::vector<std::pair<int64_t, bool>>{
           {1'000'000, true}, {10'999'000, true}, {11'000'001, false}, {-9'000'001, false}}) {
    EXPECT_EQ(Check<lcmt_task_reference>(Encode(r), now_us).ok(), ok) << now_us;
  }
  for (int64_t stamp :
       {std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::min(), int64_t{-1}}) {
    r.utime = stamp;
    EXPECT_EQ(Check<lcmt_task_reference>(Encode(r), 20'000'000).refusal, Refusal::kTimeOutOfRange);
    EXPECT_EQ(Check<lcmt_task_reference>(Encode(r)).ok(), stamp >= 0);  // no clock: >= 0
  }
  r.utime = -1;  // never: controller time starts at 0, even just after the start
  EXPECT_EQ(Check<lcmt_task_reference>(Encode(r), 200'000).refusal, Refusal::kTimeOutOfRange);
}

TEST(ValidateTest, WrongTypeBooleansAndTrailingBytesAreRefused) {
  lcmt_robot_state state{};
  EXPECT_EQ(Check<lcmt_task_reference>(Encode(state)).refusal, Refusal::kWrongType);
  Bytes b = Encode(Reference());
  b[b.size() - 5] = 2;  // last_chunk
  EXPECT_EQ(Check<lcmt_task_reference>(b).refusal, Refusal::kNotBoolean);
  b = Encode(Reference());
  b.push_back(0);
  const Verdict v = Check<lcmt_task_reference>(b);
  EXPECT_EQ(v.refusal, Refusal::kTrailingBytes);
  EXPECT_EQ(v.detail, "1 bytes after the " + std::to_string(b.size() - 1) + " of the message");
  EXPECT_STREQ(ToString(Refusal::kTrailingBytes), "trailing bytes");
}

// Whatever the validator passes, lcm-gen's decoder reads exactly to the end (random bytes,
// insertions, truncations and overwritten counts of valid messages of several types).
template <typename Msg>
void PassedMeansDecodable(const Msg& valid, std::mt19937& rng, int* passed, int* refused) {
  const Bytes base = Encode(valid);
  std::uniform_int_distribution<int> byte(0, 255), kind(0, 3);
  for (int trial = 0; trial < 3000; ++trial) {
    Bytes b = base;
    const size_t at = 8 + rng() % (b.size() - 8);
    switch (kind(rng)) {
      case 0:
        b[at] = static_cast<uint8_t>(byte(rng));
        break;
      case 1:
        b.insert(b.begin() + at, static_cast<uint8_t>(byte(rng)));
        break;
      case 2:
        b.resize(at);
        break;
      default:
        if (at + 4 <= b.size()) PutBigEndian(&b, at, rng() % 16, 4);  // a small plausible count
    }
    const Verdict v = Check<Msg>(b);
    if (!v.ok()) {
      ++*refused;
      continue;
    }
    ++*passed;
    Msg out;
    ASSERT_EQ(out.decode(b.data(), 0, static_cast<int>(b.size())), static_cast<int>(b.size()));
  }
}

TEST(ValidateTest, WhateverPassesDecodesExactly) {
  int passed = 0, refused = 0;
  for (unsigned seed = 0; seed < 8; ++seed) {
    std::mt19937 rng(seed);
    PassedMeansDecodable(Reference(), rng, &passed, &refused);
    PassedMeansDecodable(Spec(), rng, &passed, &refused);
    PassedMeansDecodable(Request(), rng, &passed, &refused);
    PassedMeansDecodable(Plan(), rng, &passed, &refused);
    lcmt_command command{};
    command.command = "hold";
    PassedMeansDecodable(command, rng, &passed, &refused);
  }
  EXPECT_GT(passed, 1000);  // the property was exercised on both sides
  EXPECT_GT(refused, 10000);
}

TEST(ValidateTest, EveryTypeOfTheSchemaIsFound) {
  EXPECT_NE(FindSchema("lcmt_controller_spec"), nullptr);
  EXPECT_NE(FindSchema("lcmt_camera_image"), nullptr);
  EXPECT_EQ(FindSchema("lcmt_nothing"), nullptr);
  EXPECT_EQ(FindSchema("lcmt_task_spec")->min_size, 79);  // 8 + 6 strings + 6 + 3 doubles + 4 ints
}

}  // namespace
}  // namespace marionette::wire
