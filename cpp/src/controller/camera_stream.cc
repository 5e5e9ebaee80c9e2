// The simulated head camera in a thread of its own (camera_stream.h), for marionette-controller's
// mujoco backend and marionette-sim.
#include "marionette/controller/camera_stream.h"

#include <pthread.h>
#include <sched.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>

#include "marionette/lcm/channels.h"
#include "marionette/lcmt_camera_image.hpp"
#include "marionette/runtime/log_line.h"
#include "marionette/sim/camera_noise.h"
#include "marionette/sim/rgbd_renderer.h"

namespace marionette::controller {

CameraStream::CameraStream(const mjModel* model, lcm::LCM* lcm, CameraStreamOptions options)
    : model_(model), lcm_(lcm), options_(std::move(options)) {
  every_ = std::max(1, static_cast<int>(std::lround(1.0 / (options_.rate_hz * options_.dt))));
  states_ = std::make_unique<runtime::TripleBuffer<std::vector<double>>>(
      std::vector<double>(1 + model_->nq + 7 * model_->nmocap, 0.0));
}

CameraStream::~CameraStream() { Stop(); }

void CameraStream::Offer(int64_t utime, const mjData& d) {
  const mjModel& m = *model_;
  std::vector<double>& r = states_->write_slot();
  r[0] = static_cast<double>(utime);
  std::copy_n(d.qpos, m.nq, r.begin() + 1);
  std::copy_n(d.mocap_pos, 3 * m.nmocap, r.begin() + 1 + m.nq);
  std::copy_n(d.mocap_quat, 4 * m.nmocap, r.begin() + 1 + m.nq + 3 * m.nmocap);
  states_->Publish();
}

void CameraStream::Start() {
  if (thread_.joinable()) return;
  stop_ = false;
  thread_ = std::thread(&CameraStream::Run, this);
}

void CameraStream::Stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
}

void CameraStream::Run() {
  // Rendering takes what the loop leaves: SCHED_IDLE runs only when no other thread wants the
  // CPU, so a frame can be late but a tick never waits for one.
  sched_param idle{};
  if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &idle) != 0) {
    runtime::LogLine(options_.log_prefix,
                     " camera thread: SCHED_IDLE refused, rendering at normal priority");
  }
  const mjModel& m = *model_;
  mjData* d = mj_makeData(&m);
  std::unique_ptr<sim::RgbdRenderer> renderer;
  try {
    renderer =
        std::make_unique<sim::RgbdRenderer>(&m, options_.camera, options_.width, options_.height);
  } catch (const std::exception& e) {
    runtime::LogLine(options_.log_prefix, " camera disabled: ", e.what());
    mj_deleteData(d);
    return;
  }
  sim::RgbdFrame frame;
  sim::CameraNoise noise({options_.noise_grey, options_.depth_noise, /*seed=*/0});
  if (noise.enabled()) {
    runtime::LogLine(options_.log_prefix, " camera: sensor noise ", options_.noise_grey,
                     " grey levels, depth ", options_.depth_noise * 1e3, " mm (1 sigma)");
  }
  lcmt_camera_image msg{};
  const sim::PinholeIntrinsics& K = renderer->intrinsics();
  msg.camera_name = "head";
  msg.frame_name = options_.camera_frame;
  msg.width = K.width, msg.height = K.height;
  msg.fx = K.fx, msg.fy = K.fy, msg.cx = K.cx, msg.cy = K.cy;
  msg.depth_scale = 0.001;
  msg.num_rgb = K.width * K.height * 3;
  msg.num_depth = K.width * K.height;
  msg.depth.resize(msg.num_depth);
  while (!stop_) {
    if (!states_->Fetch()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      continue;
    }
    const std::vector<double>& r = states_->read_slot();
    std::copy_n(r.begin() + 1, m.nq, d->qpos);
    std::copy_n(r.begin() + 1 + m.nq, 3 * m.nmocap, d->mocap_pos);
    std::copy_n(r.begin() + 1 + m.nq + 3 * m.nmocap, 4 * m.nmocap, d->mocap_quat);
    mj_kinematics(&m, d);
    mj_camlight(&m, d);
    renderer->Render(*d, &frame);
    noise.Apply(&frame);  // nothing when both sigmas are 0
    msg.utime = static_cast<int64_t>(r[0]);
    msg.rgb = frame.rgb;
    for (int i = 0; i < msg.num_depth; ++i) {
      // Depth in mm; beyond int16's 32.767 m a real sensor returns nothing either: 0.
      const double mm = std::round(frame.depth[i] * 1000.0);
      msg.depth[i] = mm > 0.0 && mm <= 32767.0 ? static_cast<int16_t>(mm) : 0;
    }
    const Eigen::Isometry3d X_WC = renderer->CameraPose(*d);
    const Eigen::Quaterniond quat(X_WC.rotation());
    for (int k = 0; k < 3; ++k) msg.camera_position[k] = X_WC.translation()[k];
    msg.camera_quaternion[0] = quat.w(), msg.camera_quaternion[1] = quat.x();
    msg.camera_quaternion[2] = quat.y(), msg.camera_quaternion[3] = quat.z();
    lcm_->publish(channels::kCameraHead, &msg);
  }
  mj_deleteData(d);
}

}  // namespace marionette::controller
