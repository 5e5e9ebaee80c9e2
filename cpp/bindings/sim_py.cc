// marionette._core.sim: a MuJoCo scene (model + data) and its offscreen RGB-D renderer, for tests
// and tools (bindings only; the renderer lives in cpp/src/sim).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <string>

#include "marionette/sim/rgbd_renderer.h"

namespace py = pybind11;
namespace sim = marionette::sim;

namespace marionette::bindings {
namespace {

// Owns an mjModel loaded from MJCF and one mjData.
class MjScene {
 public:
  explicit MjScene(const std::string& path) {
    char error[1000] = "";
    model_ = mj_loadXML(path.c_str(), nullptr, error, sizeof(error));
    if (model_ == nullptr) throw std::invalid_argument("cannot load MJCF " + path + ": " + error);
    data_ = mj_makeData(model_);
    mj_forward(model_, data_);
  }
  ~MjScene() {
    mj_deleteData(data_);
    mj_deleteModel(model_);
  }
  MjScene(const MjScene&) = delete;
  MjScene& operator=(const MjScene&) = delete;

  const mjModel* model() const { return model_; }
  const mjData& data() const { return *data_; }
  int nq() const { return model_->nq; }
  Eigen::VectorXd qpos() const { return Eigen::Map<Eigen::VectorXd>(data_->qpos, model_->nq); }
  void set_qpos(const Eigen::VectorXd& q) {
    if (q.size() != model_->nq) {
      throw std::invalid_argument("qpos has size " + std::to_string(q.size()) +
                                  ", the model nq = " + std::to_string(model_->nq));
    }
    Eigen::Map<Eigen::VectorXd>(data_->qpos, model_->nq) = q;
  }
  void forward() { mj_forward(model_, data_); }
  void reset_keyframe(const std::string& name) {
    const int key = mj_name2id(model_, mjOBJ_KEY, name.c_str());
    if (key < 0) throw std::invalid_argument("no keyframe " + name + " in the scene");
    mj_resetDataKeyframe(model_, data_, key);
    mj_forward(model_, data_);
  }

  // X_WF (4 x 4) of a body, site or geom named `name` (kinematics as of the last forward()).
  Eigen::Matrix4d Pose(int type, const std::string& name) const {
    const int id = mj_name2id(model_, type, name.c_str());
    if (id < 0) throw std::invalid_argument("no such " + TypeName(type) + " in the scene: " + name);
    const double* pos = type == mjOBJ_BODY   ? data_->xpos
                        : type == mjOBJ_SITE ? data_->site_xpos
                                             : data_->geom_xpos;
    const double* mat = type == mjOBJ_BODY   ? data_->xmat
                        : type == mjOBJ_SITE ? data_->site_xmat
                                             : data_->geom_xmat;
    Eigen::Matrix4d X = Eigen::Matrix4d::Identity();
    for (int r = 0; r < 3; ++r) {
      X(r, 3) = pos[3 * id + r];
      for (int c = 0; c < 3; ++c) X(r, c) = mat[9 * id + 3 * r + c];
    }
    return X;
  }

 private:
  static std::string TypeName(int type) {
    return type == mjOBJ_BODY ? "body" : type == mjOBJ_SITE ? "site" : "geom";
  }
  mjModel* model_ = nullptr;
  mjData* data_ = nullptr;
};

}  // namespace

void RegisterSim(py::module_& parent) {
  py::module_ m = parent.def_submodule("sim", "MuJoCo scenes and the offscreen RGB-D renderer");
  py::register_exception<sim::RendererError>(m, "RendererError", PyExc_RuntimeError);

  py::class_<MjScene>(m, "MjScene", "An MJCF scene: mjModel + one mjData (forward kinematics run).")
      .def(py::init<const std::string&>(), py::arg("path"))
      .def_property_readonly("nq", &MjScene::nq)
      .def_property("qpos", &MjScene::qpos, &MjScene::set_qpos, "(nq,) generalised positions")
      .def("forward", &MjScene::forward, "mj_forward: update kinematics after setting qpos")
      .def("reset_keyframe", &MjScene::reset_keyframe, py::arg("name"),
           "mj_resetDataKeyframe then mj_forward")
      .def(
          "body_pose", [](const MjScene& s, const std::string& n) { return s.Pose(mjOBJ_BODY, n); },
          py::arg("name"), "X_WB as a 4 x 4 matrix")
      .def(
          "site_pose", [](const MjScene& s, const std::string& n) { return s.Pose(mjOBJ_SITE, n); },
          py::arg("name"), "X_WS as a 4 x 4 matrix")
      .def(
          "geom_pose", [](const MjScene& s, const std::string& n) { return s.Pose(mjOBJ_GEOM, n); },
          py::arg("name"), "X_WG as a 4 x 4 matrix");

  py::class_<sim::PinholeIntrinsics>(m, "PinholeIntrinsics")
      .def_readonly("width", &sim::PinholeIntrinsics::width)
      .def_readonly("height", &sim::PinholeIntrinsics::height)
      .def_readonly("fx", &sim::PinholeIntrinsics::fx)
      .def_readonly("fy", &sim::PinholeIntrinsics::fy)
      .def_readonly("cx", &sim::PinholeIntrinsics::cx)
      .def_readonly("cy", &sim::PinholeIntrinsics::cy);

  py::class_<sim::RgbdRenderer>(m, "RgbdRenderer",
                                "Offscreen RGB-D rendering of one camera of an MjScene (EGL).")
      .def(py::init([](const MjScene& scene, const std::string& camera, int width, int height) {
             return std::make_unique<sim::RgbdRenderer>(scene.model(), camera, width, height);
           }),
           py::arg("scene"), py::arg("camera"), py::arg("width") = 640, py::arg("height") = 480,
           py::keep_alive<1, 2>())
      .def(
          "render",
          [](sim::RgbdRenderer& r, const MjScene& scene) {
            const auto& k = r.intrinsics();
            py::array_t<std::uint8_t> rgb({k.height, k.width, 3});
            py::array_t<float> depth({k.height, k.width});
            {
              py::gil_scoped_release release;
              r.Render(scene.data(), rgb.mutable_data(), depth.mutable_data());
            }
            return py::make_tuple(rgb, depth);
          },
          py::arg("scene"), "-> (rgb (h, w, 3) uint8, depth (h, w) float32 [m], 0 = no hit)")
      .def_property_readonly("intrinsics", &sim::RgbdRenderer::intrinsics)
      .def(
          "camera_pose",
          [](const sim::RgbdRenderer& r, const MjScene& s) {
            return r.CameraPose(s.data()).matrix();
          },
          py::arg("scene"), "X_WC of the optical frame (x right, y down, z forward), 4 x 4")
      .def_property_readonly("znear", &sim::RgbdRenderer::znear)
      .def_property_readonly("zfar", &sim::RgbdRenderer::zfar);
}

}  // namespace marionette::bindings
