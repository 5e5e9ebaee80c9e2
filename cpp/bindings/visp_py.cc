// marionette._visp: the perception library (ViSP AprilTag detection, planar and RGB-D pose,
// hand-eye calibration) for Python. A module of its own so that ViSP, with Debian's OpenCV and
// Boost, is never loaded into marionette._core's Pinocchio translation units. Bindings only.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>
#include <vector>

#include "marionette/perception/apriltag_detector.h"
#include "marionette/perception/camera_intrinsics.h"
#include "marionette/perception/hand_eye.h"
#include "marionette/perception/planar_pose.h"

namespace py = pybind11;
namespace mp = marionette::perception;

namespace {

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// A 4 x 4 homogeneous matrix as an isometry; rejects anything that is not a rigid transform.
Eigen::Isometry3d ToIsometry(const Eigen::Matrix4d& M, const char* what) {
  if (!M.allFinite()) throw mp::PerceptionError(std::string(what) + " is not finite");
  const Eigen::Matrix3d R = M.topLeftCorner<3, 3>();
  if ((M.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).norm() > 1e-9 ||
      (R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || R.determinant() < 0.0) {
    throw mp::PerceptionError(std::string(what) +
                              " is not a rigid transform (4 x 4, R orthonormal)");
  }
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.matrix() = M;
  return X;
}

std::vector<Eigen::Vector3d> Points3(const RowMatrixXd& p, const char* what) {
  if (p.cols() != 3) {
    throw mp::PerceptionError(std::string(what) + " must be (n, 3), got (" +
                              std::to_string(p.rows()) + ", " + std::to_string(p.cols()) + ")");
  }
  std::vector<Eigen::Vector3d> out(p.rows());
  for (Eigen::Index i = 0; i < p.rows(); ++i) out[i] = p.row(i).transpose();
  return out;
}

std::vector<Eigen::Vector2d> Points2(const RowMatrixXd& p, const char* what) {
  if (p.cols() != 2) {
    throw mp::PerceptionError(std::string(what) + " must be (n, 2), got (" +
                              std::to_string(p.rows()) + ", " + std::to_string(p.cols()) + ")");
  }
  std::vector<Eigen::Vector2d> out(p.rows());
  for (Eigen::Index i = 0; i < p.rows(); ++i) out[i] = p.row(i).transpose();
  return out;
}

template <typename T>
void CheckImage(const py::array_t<T, py::array::c_style | py::array::forcecast>& image,
                const mp::CameraIntrinsics& k, const char* what) {
  if (image.ndim() != 2 || image.shape(0) != k.height || image.shape(1) != k.width) {
    std::string shape = "(";
    for (py::ssize_t i = 0; i < image.ndim(); ++i) {
      shape += (i ? ", " : "") + std::to_string(image.shape(i));
    }
    throw mp::PerceptionError(std::string(what) + " must be (height, width) = (" +
                              std::to_string(k.height) + ", " + std::to_string(k.width) +
                              ") as the intrinsics say, got " + shape + ")");
  }
}

}  // namespace

PYBIND11_MODULE(_visp, m) {
  m.doc() = "marionette perception over ViSP 3.5: AprilTags, planar/RGB-D pose, hand-eye";
  py::register_exception<mp::PerceptionError>(m, "PerceptionError", PyExc_ValueError);

  py::class_<mp::CameraIntrinsics>(m, "CameraIntrinsics",
                                   "Pinhole intrinsics, pixel centres at integer coordinates")
      .def(py::init([](int width, int height, double fx, double fy, double cx, double cy) {
             mp::CameraIntrinsics k{width, height, fx, fy, cx, cy};
             k.Validate();
             return k;
           }),
           py::arg("width"), py::arg("height"), py::arg("fx"), py::arg("fy"), py::arg("cx"),
           py::arg("cy"))
      .def_readonly("width", &mp::CameraIntrinsics::width)
      .def_readonly("height", &mp::CameraIntrinsics::height)
      .def_readonly("fx", &mp::CameraIntrinsics::fx)
      .def_readonly("fy", &mp::CameraIntrinsics::fy)
      .def_readonly("cx", &mp::CameraIntrinsics::cx)
      .def_readonly("cy", &mp::CameraIntrinsics::cy);

  py::class_<mp::PoseHypothesis>(m, "PoseHypothesis")
      .def_property_readonly("X_CT", [](const mp::PoseHypothesis& h) { return h.X_CT.matrix(); })
      .def_readonly("reprojection_error", &mp::PoseHypothesis::reprojection_error,
                    "sum of squared corner distances [px^2]");

  py::class_<mp::TagDetection>(m, "TagDetection")
      .def_readonly("id", &mp::TagDetection::id)
      .def_property_readonly(
          "corners",
          [](const mp::TagDetection& d) {
            Eigen::Matrix<double, 4, 2, Eigen::RowMajor> c;
            for (int i = 0; i < 4; ++i) c.row(i) = d.corners[i].transpose();
            return c;
          },
          "(4, 2) pixel corners (u, v) in tag_corners() order")
      .def_readonly("tag_size", &mp::TagDetection::tag_size)
      .def_readonly("has_pose", &mp::TagDetection::has_pose)
      .def_readonly("has_second", &mp::TagDetection::has_second)
      .def_property_readonly("hypotheses", [](const mp::TagDetection& d) {
        return std::vector<mp::PoseHypothesis>(d.hypotheses.begin(), d.hypotheses.end());
      });

  py::class_<mp::DetectionStats>(m, "DetectionStats", "what the last detect call did")
      .def_readonly("noise_sigma", &mp::DetectionStats::noise_sigma,
                    "estimated pixel noise [grey levels]")
      .def_readonly("quad_sigma", &mp::DetectionStats::quad_sigma,
                    "blur applied for quad detection [px]")
      .def_readonly("pixels_searched", &mp::DetectionStats::pixels_searched);

  py::class_<mp::AprilTagDetector>(m, "AprilTagDetector", "tag36h11 detector (ViSP/AprilTag 3)")
      .def(py::init([](float quad_decimate, float quad_sigma, int num_threads, bool refine_edges,
                       double decode_sharpening, bool noise_adaptive_blur) {
             return std::make_unique<mp::AprilTagDetector>(
                 mp::AprilTagDetectorOptions{quad_decimate, quad_sigma, num_threads, refine_edges,
                                             decode_sharpening, noise_adaptive_blur});
           }),
           py::arg("quad_decimate") = 1.0f, py::arg("quad_sigma") = 0.0f,
           py::arg("num_threads") = 1, py::arg("refine_edges") = true,
           py::arg("decode_sharpening") = 0.25, py::arg("noise_adaptive_blur") = true)
      .def(
          "detect",
          [](mp::AprilTagDetector& d,
             const py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>& gray,
             const mp::CameraIntrinsics& k, const std::map<int, double>& tag_sizes,
             double default_size, const std::vector<std::array<int, 4>>& regions) {
            CheckImage(gray, k, "gray image");
            const mp::TagSizes sizes{default_size, tag_sizes};
            std::vector<mp::PixelBox> boxes;
            for (const auto& r : regions) boxes.push_back({r[0], r[1], r[2], r[3]});
            py::gil_scoped_release release;
            return d.Detect(gray.data(), k.width, k.height, k, sizes, boxes);
          },
          py::arg("gray"), py::arg("intrinsics"), py::arg("tag_sizes") = std::map<int, double>{},
          py::arg("default_size") = 0.0, py::arg("regions") = std::vector<std::array<int, 4>>{},
          "gray (height, width) uint8 -> [TagDetection]; poses for ids with a known size [m]; "
          "regions: (u0, v0, u1, v1) pixel boxes to search (columns u0..u1-1, rows v0..v1-1), "
          "none: the whole image")
      .def_property_readonly("last_stats", &mp::AprilTagDetector::last_stats);

  m.def(
      "estimate_noise_sigma",
      [](const py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>& gray,
         int row_step) {
        if (gray.ndim() != 2) throw mp::PerceptionError("gray must be a (height, width) image");
        const int h = static_cast<int>(gray.shape(0)), w = static_cast<int>(gray.shape(1));
        return mp::EstimateNoiseSigma(gray.data(), w, h, w, row_step);
      },
      py::arg("gray"), py::arg("row_step") = 2,
      "standard deviation of the pixel noise [grey levels] (Immerkaer's mask, median)");
  m.def("blur_for_noise", &mp::BlurForNoise, py::arg("noise_sigma"),
        "the quad-detection blur [px] the adaptive detector applies for that noise");

  m.def(
      "tag_corners",
      [](double size) {
        const auto c = mp::TagCorners(size);
        Eigen::Matrix<double, 4, 3, Eigen::RowMajor> out;
        for (int i = 0; i < 4; ++i) out.row(i) = c[i].transpose();
        return out;
      },
      py::arg("tag_size"), "(4, 3) corners of the black square in the tag frame [m]");

  py::class_<mp::PoseEstimate>(m, "PoseEstimate")
      .def_readonly("ok", &mp::PoseEstimate::ok)
      .def_property_readonly("X_CO", [](const mp::PoseEstimate& e) { return e.X_CO.matrix(); })
      .def_readonly("reprojection_error", &mp::PoseEstimate::reprojection_error,
                    "sum of squared pixel distances [px^2]")
      .def_readonly("num_points", &mp::PoseEstimate::num_points)
      .def_readonly("confidence", &mp::PoseEstimate::confidence)
      .def_readonly("depth_sigma", &mp::PoseEstimate::depth_sigma,
                    "RGB-D refinement: the depth noise the residuals showed, weighted with [m]");

  m.def(
      "reprojection_error",
      [](const RowMatrixXd& p_O, const RowMatrixXd& uv, const mp::CameraIntrinsics& k,
         const Eigen::Matrix4d& X_CO) {
        return mp::ReprojectionError(Points3(p_O, "p_O"), Points2(uv, "uv"), k,
                                     ToIsometry(X_CO, "X_CO"));
      },
      py::arg("p_O"), py::arg("uv"), py::arg("intrinsics"), py::arg("X_CO"),
      "sum of squared pixel distances [px^2] (inf if a point is behind the camera)");
  m.def(
      "refine_pose",
      [](const RowMatrixXd& p_O, const RowMatrixXd& uv, const mp::CameraIntrinsics& k,
         const Eigen::Matrix4d& X_CO_initial) {
        return mp::RefinePose(Points3(p_O, "p_O"), Points2(uv, "uv"), k,
                              ToIsometry(X_CO_initial, "X_CO_initial"));
      },
      py::arg("p_O"), py::arg("uv"), py::arg("intrinsics"), py::arg("X_CO_initial"),
      "Gauss-Newton (ViSP VVS) on the reprojection error from an initial pose");
  m.def(
      "pose_from_rgbd",
      [](const py::array_t<float, py::array::c_style | py::array::forcecast>& depth,
         const mp::CameraIntrinsics& k, const RowMatrixXd& corners, const RowMatrixXd& p_O) {
        CheckImage(depth, k, "depth");
        return mp::PoseFromRgbd(depth.data(), k, Points2(corners, "corners"), Points3(p_O, "p_O"));
      },
      py::arg("depth"), py::arg("intrinsics"), py::arg("corners"), py::arg("p_O"),
      "planar pose from a depth map [m] and the corners of one planar set (ViSP)");

  m.def(
      "refine_pose_rgbd",
      [](const RowMatrixXd& p_O, const RowMatrixXd& uv, const std::vector<py::tuple>& planes,
         const py::array_t<float, py::array::c_style | py::array::forcecast>& depth,
         const mp::CameraIntrinsics& k, const Eigen::Matrix4d& X_CO_initial, double sigma_pixel,
         double sigma_depth, double polygon_scale) {
        CheckImage(depth, k, "depth");
        std::vector<mp::DepthPlane> native;
        for (const py::tuple& t : planes) {
          if (t.size() != 3) {
            throw mp::PerceptionError("a plane is (polygon (m, 2), normal_O (3,), offset_O)");
          }
          native.push_back({Points2(t[0].cast<RowMatrixXd>(), "plane polygon"),
                            t[1].cast<Eigen::Vector3d>(), t[2].cast<double>()});
        }
        mp::RgbdRefineOptions options;
        options.sigma_pixel = sigma_pixel;
        options.sigma_depth = sigma_depth;
        options.polygon_scale = polygon_scale;
        const auto p = Points3(p_O, "p_O");
        const auto q = Points2(uv, "uv");
        const Eigen::Isometry3d X0 = ToIsometry(X_CO_initial, "X_CO_initial");
        py::gil_scoped_release release;
        return mp::RefinePoseRgbd(p, q, native, depth.data(), k, X0, options);
      },
      py::arg("p_O"), py::arg("uv"), py::arg("planes"), py::arg("depth"), py::arg("intrinsics"),
      py::arg("X_CO_initial"), py::arg("sigma_pixel") = 0.3, py::arg("sigma_depth") = 0.003,
      py::arg("polygon_scale") = 0.8,
      "depth-fused Gauss-Newton: corners + point-to-plane distances of depth pixels");

  py::class_<mp::HandEyeResult>(m, "HandEyeResult")
      .def_property_readonly("X_EC", [](const mp::HandEyeResult& r) { return r.X_EC.matrix(); })
      .def_property_readonly("X_RT", [](const mp::HandEyeResult& r) { return r.X_RT.matrix(); })
      .def_readonly("rms_position", &mp::HandEyeResult::rms_position)
      .def_readonly("rms_rotation", &mp::HandEyeResult::rms_rotation);
  m.def(
      "calibrate_hand_eye",
      [](const std::vector<Eigen::Matrix4d>& X_RE, const std::vector<Eigen::Matrix4d>& X_CT) {
        std::vector<Eigen::Isometry3d> a, b;
        for (const auto& M : X_RE) a.push_back(ToIsometry(M, "X_RE"));
        for (const auto& M : X_CT) b.push_back(ToIsometry(M, "X_CT"));
        return mp::CalibrateHandEye(a, b);
      },
      py::arg("X_RE"), py::arg("X_CT"),
      "eye-in-hand calibration: X_EC from pairs (base <- effector, camera <- target)");
}
