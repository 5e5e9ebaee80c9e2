#pragma once
// Offscreen RGB-D rendering of one MuJoCo camera (EGL, no display): the head camera of the
// simulated robot, rendered in its own thread by the controller and by tests.

#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace marionette::sim {

/// Rendering failed (no EGL display, unknown camera, bad size, wrong thread...).
class RendererError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Pinhole intrinsics of a rendered image, pixel centres at integer coordinates:
/// pixel (u, v) (column, row, top row v = 0) sees the ray (x, y, 1) with
/// u = fx x + cx, v = fy y + cy in the optical frame (x right, y down, z forward).
struct PinholeIntrinsics {
  int width = 0;
  int height = 0;
  double fx = 0.0;  // [px]
  double fy = 0.0;  // [px]
  double cx = 0.0;  // [px]
  double cy = 0.0;  // [px]
};

/// One RGB-D frame: row-major, top row first.
struct RgbdFrame {
  std::vector<std::uint8_t> rgb;  // (height x width x 3) RGB8
  std::vector<float> depth;       // (height x width) metric depth along the optical axis z [m],
                                  // 0 where nothing was hit before zfar
};

/// Renders the model camera `camera_name` into `width x height` RGB8 + metric depth.
///
/// The constructor creates an EGL context (surfaceless Mesa platform, falling back to the
/// default display) and MuJoCo's render context; both belong to this object. Render() makes the
/// context current in the calling thread and releases it on return, so one renderer may be
/// created in one thread and used in another (the controller's render thread), but never by two
/// threads at once. The model must outlive the renderer.
///
/// Depth: MuJoCo 2.2 draws with glFrustum(near, far), near = vis.map.znear * stat.extent,
/// far = vis.map.zfar * stat.extent, so the window depth d in [0, 1] maps to the optical-axis
/// depth z = near / (1 - d (1 - near / far)); d = 1 (cleared, nothing hit) gives 0.
class RgbdRenderer {
 public:
  RgbdRenderer(const mjModel* model, const std::string& camera_name, int width, int height);
  ~RgbdRenderer();
  RgbdRenderer(const RgbdRenderer&) = delete;
  RgbdRenderer& operator=(const RgbdRenderer&) = delete;

  /// Renders the state `data` (its kinematics must be current: mj_forward or mj_step ran).
  /// Writes rgb (height*width*3) and depth (height*width) [m]; either pointer may be null.
  void Render(const mjData& data, std::uint8_t* rgb, float* depth);
  /// Same, into a frame whose buffers are resized once (no allocation after the first call).
  void Render(const mjData& data, RgbdFrame* frame);

  /// fx = fy = (height / 2) / tan(fovy / 2); principal point at the image centre.
  const PinholeIntrinsics& intrinsics() const { return intrinsics_; }
  /// X_WC: pose of the optical frame (x right, y down, z forward) in the world for `data`
  /// (MuJoCo's camera frame looks along -z with y up: a half-turn about x away).
  Eigen::Isometry3d CameraPose(const mjData& data) const;
  int camera_id() const { return camera_id_; }
  double znear() const { return znear_; }  // [m]
  double zfar() const { return zfar_; }    // [m]

 private:
  struct Egl;
  class ScopedCurrent;

  const mjModel* model_;
  mjModel* render_model_ = nullptr;  // copy with a larger offscreen buffer, when needed
  int camera_id_ = -1;
  PinholeIntrinsics intrinsics_;
  double znear_ = 0.0;
  double zfar_ = 0.0;
  std::unique_ptr<Egl> egl_;
  mjvScene scene_;
  mjvCamera camera_;
  mjvOption option_;
  mjrContext context_;
  std::vector<std::uint8_t> rgb_flipped_;  // (height x width x 3), OpenGL's bottom row first
  std::vector<float> depth_window_;        // (height x width) window depth in [0, 1]
};

}  // namespace marionette::sim
