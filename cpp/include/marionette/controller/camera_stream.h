#pragma once
/// CameraStream: the simulated head camera (CAMERA_HEAD) rendered in a thread of its own from
/// snapshots of a MuJoCo state, so that the physics never waits for a frame. Shared by
/// marionette-controller's mujoco backend and marionette-sim.
///
///   loop thread    if (camera.Due(tick)) camera.Offer(utime, data);   // copies qpos + mocap
///   camera thread  takes the newest snapshot, renders RGB-D (EGL, sim::RgbdRenderer), adds the
///                  sensor noise (sim::CameraNoise), publishes lcmt_camera_image on CAMERA_HEAD
///
/// The camera thread runs at SCHED_IDLE (only when no other thread wants the CPU): a frame can
/// be late or skipped, a tick never waits. A camera that cannot be created (no EGL) is logged and
/// the stream publishes nothing.

#include <mujoco/mujoco.h>

#include <atomic>
#include <cstdint>
#include <lcm/lcm-cpp.hpp>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "marionette/runtime/triple_buffer.h"

namespace marionette::controller {

struct CameraStreamOptions {
  std::string camera;        ///< MuJoCo camera name (robot.yaml's camera)
  std::string camera_frame;  ///< the Pinocchio frame of its optical centre (in the message)
  double rate_hz = 30.0;     ///< frames per second of robot time
  double dt = 1e-3;          ///< the control period [s] (Due counts ticks of it)
  int width = 640, height = 480;
  double noise_grey = 0.0;   ///< Gaussian image noise [grey levels, 1 sigma]
  double depth_noise = 0.0;  ///< Gaussian depth noise [m, 1 sigma]
  std::string log_prefix = "[controller]";
};

class CameraStream {
 public:
  /// `model` and `lcm` must outlive the stream. Nothing runs before Start().
  CameraStream(const mjModel* model, lcm::LCM* lcm, CameraStreamOptions options);
  ~CameraStream();
  CameraStream(const CameraStream&) = delete;
  CameraStream& operator=(const CameraStream&) = delete;

  /// Whether tick `tick` (of options.dt) is one the camera samples.
  bool Due(int64_t tick) const { return tick % every_ == 0; }
  /// The loop's side: a snapshot of `d`'s qpos and mocap poses at robot time `utime` [us]. No
  /// allocation, no lock.
  void Offer(int64_t utime, const mjData& d);
  /// Starts the rendering thread; Stop() ends it (also at destruction).
  void Start();
  void Stop();

 private:
  void Run();

  const mjModel* model_;
  lcm::LCM* lcm_;
  CameraStreamOptions options_;
  int every_ = 1;
  std::unique_ptr<runtime::TripleBuffer<std::vector<double>>> states_;  // utime, qpos, mocap
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace marionette::controller
