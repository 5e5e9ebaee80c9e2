// marionette-sim's loop in this process (sim_driver/sim_driver.h), the UR10 alone, in lockstep
// with an answering thread on a private LCM URL: it allocates nothing per cycle once warm.
#include "marionette/sim_driver/sim_driver.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cstdio>
#include <lcm/lcm-cpp.hpp>
#include <random>
#include <thread>
#include <vector>

#include "allocation_counter.h"
#include "marionette/lcm/channels.h"
#include "marionette/lcmt_driver_command.hpp"
#include "marionette/lcmt_driver_state.hpp"

namespace marionette::sim_driver {
namespace {

// Answers every DRIVER_STATE with a command holding the first state's positions.
class Answerer {
 public:
  explicit Answerer(const std::string& url) : lcm_(url) {
    lcm_.subscribe(channels::kDriverState, &Answerer::Handle, this);
    thread_ = std::thread([this] {
      while (!stop_) lcm_.handleTimeout(10);
    });
  }
  ~Answerer() {
    stop_ = true;
    thread_.join();
  }
  int64_t answered() const { return answered_; }

 private:
  void Handle(const lcm::ReceiveBuffer* rbuf, const std::string&) {
    lcmt_driver_state s;
    if (s.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) !=
        static_cast<int>(rbuf->data_size))
      return;
    if (command_.num_joints == 0) {
      command_.protocol_version = 1;
      command_.num_joints = s.num_joints;
      command_.joint_name = s.joint_name;
      command_.joint_position = s.joint_position;
      command_.joint_velocity.assign(s.num_joints, 0.0);
      command_.joint_effort.assign(s.num_joints, 0.0);
    }
    command_.utime = s.utime;
    command_.sequence = s.sequence;
    lcm_.publish(channels::kDriverCommand, &command_);
    ++answered_;
  }

  lcm::LCM lcm_;
  lcmt_driver_command command_{};
  std::atomic<int64_t> answered_{0};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

std::string PrivateUrl() {
  std::random_device seed;
  return "udpm://239.255.76.67:" + std::to_string(20000 + seed() % 40000) + "?ttl=0";
}

// The allocations of the loop's thread over a lockstep run of `seconds` of robot time.
int64_t RunAllocations(double seconds, int64_t* answered) {
  SimOptions o;
  o.robot = "ur10";
  o.models_dir = MARIONETTE_MODELS_DIR;
  o.lcm_url = PrivateUrl();
  o.speed = 0.0;
  o.duration = seconds;
  o.camera_rate = 0.0;
  Answerer answerer(o.lcm_url);
  SimDriver driver(o);
  testing::ScopedAllocationCounter counter;
  EXPECT_EQ(driver.Run(), 0);
  *answered = answerer.answered();
  return counter.allocations();
}

TEST(SimDriverTest, LockstepCyclesDoNotAllocate) {
  int64_t short_answers = 0, long_answers = 0;
  const int64_t short_run = RunAllocations(0.2, &short_answers);
  const int64_t long_run = RunAllocations(1.2, &long_answers);
  std::printf("loop thread: %lld allocations in 200 cycles, %lld in 1200\n",
              static_cast<long long>(short_run), static_cast<long long>(long_run));
  EXPECT_GE(short_answers, 200);
  EXPECT_GE(long_answers, 1200);
  // The same start-up and summary; 1000 more cycles add nothing (a few for LCM's first messages
  // on a channel would be tolerable, not one per cycle).
  EXPECT_LE(long_run - short_run, 10)
      << short_run << " allocations in 200 cycles, " << long_run << " in 1200";
}

}  // namespace
}  // namespace marionette::sim_driver
