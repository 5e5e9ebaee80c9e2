#include "marionette/sim/rgbd_renderer.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <mutex>

#ifndef EGL_PLATFORM_SURFACELESS_MESA
#define EGL_PLATFORM_SURFACELESS_MESA 0x31DD
#endif

namespace marionette::sim {

struct RgbdRenderer::Egl {
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
};

namespace {

// MuJoCo's GL loader and context creation keep process-wide state: one construction at a time.
std::mutex& ContextCreationMutex() {
  static std::mutex m;
  return m;
}

std::string EglErrorString(const char* what) {
  char buffer[128];
  std::snprintf(buffer, sizeof(buffer), "%s failed (EGL error 0x%04x)", what, eglGetError());
  return buffer;
}

// Mesa's surfaceless platform needs neither a display server nor a GPU (llvmpipe); the default
// display is the fallback for drivers that only offer that one (EGL_PLATFORM=surfaceless).
EGLDisplay OpenDisplay() {
  auto get_platform_display = reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(
      eglGetProcAddress("eglGetPlatformDisplayEXT"));
  EGLDisplay display = EGL_NO_DISPLAY;
  if (get_platform_display != nullptr) {
    display = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
  }
  EGLint major = 0, minor = 0;
  if (display != EGL_NO_DISPLAY && eglInitialize(display, &major, &minor) == EGL_TRUE) {
    return display;
  }
  display = eglGetDisplay(EGL_DEFAULT_DISPLAY);
  if (display == EGL_NO_DISPLAY || eglInitialize(display, &major, &minor) != EGL_TRUE) {
    throw RendererError(EglErrorString("RgbdRenderer: no EGL display; eglInitialize"));
  }
  return display;
}

}  // namespace

// Makes the renderer's context current in this thread for the scope, then releases it so that
// another thread may take it next time.
class RgbdRenderer::ScopedCurrent {
 public:
  explicit ScopedCurrent(const Egl& egl) : egl_(egl) {
    if (eglMakeCurrent(egl_.display, EGL_NO_SURFACE, EGL_NO_SURFACE, egl_.context) != EGL_TRUE) {
      throw RendererError(EglErrorString(
          "RgbdRenderer: eglMakeCurrent (is the renderer used by two threads at once?)"));
    }
  }
  ~ScopedCurrent() { eglMakeCurrent(egl_.display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT); }
  ScopedCurrent(const ScopedCurrent&) = delete;
  ScopedCurrent& operator=(const ScopedCurrent&) = delete;

 private:
  const Egl& egl_;
};

RgbdRenderer::RgbdRenderer(const mjModel* model, const std::string& camera_name, int width,
                           int height)
    : model_(model), egl_(std::make_unique<Egl>()) {
  if (model == nullptr) throw RendererError("RgbdRenderer: model is null");
  if (width <= 0 || height <= 0 || width > 8192 || height > 8192) {
    throw RendererError("RgbdRenderer: image size must be in [1, 8192]^2, got " +
                        std::to_string(width) + " x " + std::to_string(height));
  }
  camera_id_ = mj_name2id(model, mjOBJ_CAMERA, camera_name.c_str());
  if (camera_id_ < 0) {
    std::string names;
    for (int i = 0; i < model->ncam; ++i) {
      names += (i ? ", " : "") + std::string(model->names + model->name_camadr[i]);
    }
    throw RendererError("RgbdRenderer: no camera '" + camera_name +
                        "' in the model (cameras: " + (names.empty() ? "none" : names) + ")");
  }
  const double fovy = model->cam_fovy[camera_id_] * M_PI / 180.0;
  intrinsics_.width = width;
  intrinsics_.height = height;
  intrinsics_.fy = 0.5 * height / std::tan(0.5 * fovy);
  intrinsics_.fx = intrinsics_.fy;  // MuJoCo widens the frustum to the viewport's aspect ratio
  // OpenGL pixel i covers [i, i + 1): its centre i + 1/2 sits at the frustum centre w / 2.
  intrinsics_.cx = 0.5 * (width - 1);
  intrinsics_.cy = 0.5 * (height - 1);
  znear_ = model->vis.map.znear * model->stat.extent;
  zfar_ = model->vis.map.zfar * model->stat.extent;

  // The offscreen framebuffer is sized from the model (<visual><global offwidth offheight/>);
  // enlarge it on a private copy rather than ask every scene to declare it. The copy also drops
  // multisampling: a depth camera has no anti-aliasing, and 4x MSAA in Mesa's software
  // rasteriser costs more than the rest of the frame.
  render_model_ = mj_copyModel(nullptr, model);
  render_model_->vis.global.offwidth = std::max(width, model->vis.global.offwidth);
  render_model_->vis.global.offheight = std::max(height, model->vis.global.offheight);
  render_model_->vis.quality.offsamples = 0;
  const mjModel* context_model = render_model_;

  std::lock_guard<std::mutex> lock(ContextCreationMutex());
  egl_->display = OpenDisplay();
  const EGLint config_attributes[] = {EGL_RED_SIZE,
                                      8,
                                      EGL_GREEN_SIZE,
                                      8,
                                      EGL_BLUE_SIZE,
                                      8,
                                      EGL_ALPHA_SIZE,
                                      8,
                                      EGL_DEPTH_SIZE,
                                      24,
                                      EGL_STENCIL_SIZE,
                                      8,
                                      EGL_COLOR_BUFFER_TYPE,
                                      EGL_RGB_BUFFER,
                                      EGL_SURFACE_TYPE,
                                      EGL_PBUFFER_BIT,
                                      EGL_RENDERABLE_TYPE,
                                      EGL_OPENGL_BIT,
                                      EGL_NONE};
  EGLConfig config;
  EGLint num_configs = 0;
  if (eglChooseConfig(egl_->display, config_attributes, &config, 1, &num_configs) != EGL_TRUE ||
      num_configs < 1) {
    throw RendererError(EglErrorString("RgbdRenderer: eglChooseConfig (RGBA8, depth 24, OpenGL)"));
  }
  if (eglBindAPI(EGL_OPENGL_API) != EGL_TRUE) {
    throw RendererError(EglErrorString("RgbdRenderer: eglBindAPI(OpenGL)"));
  }
  egl_->context = eglCreateContext(egl_->display, config, EGL_NO_CONTEXT, nullptr);
  if (egl_->context == EGL_NO_CONTEXT) {
    throw RendererError(EglErrorString("RgbdRenderer: eglCreateContext"));
  }

  mjv_defaultScene(&scene_);
  mjv_defaultCamera(&camera_);
  mjv_defaultOption(&option_);
  // A camera sees no laser beam in the air: MuJoCo would draw each rangefinder's ray (colour and
  // depth).
  option_.flags[mjVIS_RANGEFINDER] = 0;
  mjr_defaultContext(&context_);
  camera_.type = mjCAMERA_FIXED;
  camera_.fixedcamid = camera_id_;
  {
    ScopedCurrent current(*egl_);
    mjv_makeScene(model, &scene_, 2000);
    // A camera, not a viewer: no shadows, reflections or skybox. With Mesa's software
    // rasteriser they cost most of the frame (measured: 97 ms -> see bench/camera).
    scene_.flags[mjRND_SHADOW] = 0;
    scene_.flags[mjRND_REFLECTION] = 0;
    scene_.flags[mjRND_SKYBOX] = 0;
    mjr_makeContext(context_model, &context_, mjFONTSCALE_100);
    mjr_setBuffer(mjFB_OFFSCREEN, &context_);
    if (context_.currentBuffer != mjFB_OFFSCREEN || context_.offWidth < width ||
        context_.offHeight < height) {
      throw RendererError("RgbdRenderer: MuJoCo could not create a " + std::to_string(width) +
                          " x " + std::to_string(height) + " offscreen buffer");
    }
  }
  rgb_flipped_.resize(static_cast<size_t>(width) * height * 3);
  depth_window_.resize(static_cast<size_t>(width) * height);
}

RgbdRenderer::~RgbdRenderer() {
  if (egl_ && egl_->context != EGL_NO_CONTEXT) {
    if (eglMakeCurrent(egl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, egl_->context) == EGL_TRUE) {
      mjr_freeContext(&context_);
      eglMakeCurrent(egl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    }
    eglDestroyContext(egl_->display, egl_->context);
    // No eglTerminate: the display is shared by every renderer of the process.
  }
  mjv_freeScene(&scene_);
  if (render_model_ != nullptr) mj_deleteModel(render_model_);
}

void RgbdRenderer::Render(const mjData& data, std::uint8_t* rgb, float* depth) {
  const int w = intrinsics_.width;
  const int h = intrinsics_.height;
  ScopedCurrent current(*egl_);
  // mjv_updateScene only reads the kinematics of `data`; its C signature is not const-correct.
  mjv_updateScene(model_, const_cast<mjData*>(&data), &option_, nullptr, &camera_, mjCAT_ALL,
                  &scene_);
  const mjrRect viewport = {0, 0, w, h};
  mjr_setBuffer(mjFB_OFFSCREEN, &context_);
  mjr_render(viewport, &scene_, &context_);
  mjr_readPixels(rgb ? rgb_flipped_.data() : nullptr, depth ? depth_window_.data() : nullptr,
                 viewport, &context_);
  // OpenGL returns the bottom row first; images are stored top row first.
  const size_t row_bytes = static_cast<size_t>(w) * 3;
  for (int v = 0; v < h; ++v) {
    const int gl_row = h - 1 - v;
    if (rgb != nullptr) {
      std::memcpy(rgb + v * row_bytes, rgb_flipped_.data() + gl_row * row_bytes, row_bytes);
    }
    if (depth != nullptr) {
      const float* in = depth_window_.data() + static_cast<size_t>(gl_row) * w;
      float* out = depth + static_cast<size_t>(v) * w;
      const double ratio = 1.0 - znear_ / zfar_;
      for (int u = 0; u < w; ++u) {
        const double d = in[u];
        // Inverse of glFrustum's depth: d = (1/n - 1/z) / (1/n - 1/f).
        out[u] = d >= 1.0 ? 0.0f : static_cast<float>(znear_ / (1.0 - d * ratio));
      }
    }
  }
}

void RgbdRenderer::Render(const mjData& data, RgbdFrame* frame) {
  const size_t n = static_cast<size_t>(intrinsics_.width) * intrinsics_.height;
  frame->rgb.resize(3 * n);
  frame->depth.resize(n);
  Render(data, frame->rgb.data(), frame->depth.data());
}

Eigen::Isometry3d RgbdRenderer::CameraPose(const mjData& data) const {
  Eigen::Isometry3d X_WM = Eigen::Isometry3d::Identity();  // MuJoCo camera frame (-z forward)
  for (int r = 0; r < 3; ++r) {
    X_WM.translation()[r] = data.cam_xpos[3 * camera_id_ + r];
    for (int c = 0; c < 3; ++c) X_WM.linear()(r, c) = data.cam_xmat[9 * camera_id_ + 3 * r + c];
  }
  Eigen::Isometry3d X_MC = Eigen::Isometry3d::Identity();
  X_MC.linear() = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  return X_WM * X_MC;
}

}  // namespace marionette::sim
