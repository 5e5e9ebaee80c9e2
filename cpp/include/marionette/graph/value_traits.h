#pragma once
/// What the graph needs to know about a signal value type T: its name, its shape, and how to
/// copy it to and from a flat array of doubles (introspection, tracing, Python, LCM).
/// Supported: double, int, bool, Eigen::VectorXd, Eigen::MatrixXd, pinocchio::SE3.

#include <Eigen/Core>
#include <cmath>
#include <pinocchio/spatial/se3.hpp>

namespace marionette::graph {

/// rows x cols of a value: scalars 1 x 1, vectors n x 1, matrices r x c, SE3 4 x 4 (homogeneous).
struct Shape {
  int rows = 1;
  int cols = 1;
  int size() const { return rows * cols; }
  bool operator==(const Shape& o) const { return rows == o.rows && cols == o.cols; }
  bool operator!=(const Shape& o) const { return !(*this == o); }
};

template <typename T>
struct ValueTraits;  // specialised below; a missing specialisation is a compile error

template <typename Scalar>
struct ScalarTraits {
  static Shape ShapeOf(const Scalar&) { return {1, 1}; }
  static void Flatten(const Scalar& v, double* out) { out[0] = static_cast<double>(v); }
  static void Unflatten(const double* in, Scalar* v) { *v = static_cast<Scalar>(in[0]); }
  static bool IsFinite(const Scalar& v) { return std::isfinite(static_cast<double>(v)); }
};

template <>
struct ValueTraits<double> : ScalarTraits<double> {
  static constexpr const char* kName = "double";
};
template <>
struct ValueTraits<int> : ScalarTraits<int> {
  static constexpr const char* kName = "int";
};
template <>
struct ValueTraits<bool> : ScalarTraits<bool> {
  static constexpr const char* kName = "bool";
  static void Unflatten(const double* in, bool* v) { *v = in[0] != 0.0; }
};

/// Vectors and matrices flatten column-major (Eigen's storage order).
template <>
struct ValueTraits<Eigen::VectorXd> {
  static constexpr const char* kName = "vector";
  static Shape ShapeOf(const Eigen::VectorXd& v) { return {static_cast<int>(v.size()), 1}; }
  static void Flatten(const Eigen::VectorXd& v, double* out) {
    Eigen::Map<Eigen::VectorXd>(out, v.size()) = v;
  }
  static void Unflatten(const double* in, Eigen::VectorXd* v) {
    *v = Eigen::Map<const Eigen::VectorXd>(in, v->size());
  }
  static bool IsFinite(const Eigen::VectorXd& v) { return v.allFinite(); }
};

template <>
struct ValueTraits<Eigen::MatrixXd> {
  static constexpr const char* kName = "matrix";
  static Shape ShapeOf(const Eigen::MatrixXd& m) {
    return {static_cast<int>(m.rows()), static_cast<int>(m.cols())};
  }
  static void Flatten(const Eigen::MatrixXd& m, double* out) {
    Eigen::Map<Eigen::MatrixXd>(out, m.rows(), m.cols()) = m;
  }
  static void Unflatten(const double* in, Eigen::MatrixXd* m) {
    *m = Eigen::Map<const Eigen::MatrixXd>(in, m->rows(), m->cols());
  }
  static bool IsFinite(const Eigen::MatrixXd& m) { return m.allFinite(); }
};

/// SE3 as its 4 x 4 homogeneous matrix, column-major.
template <>
struct ValueTraits<pinocchio::SE3> {
  static constexpr const char* kName = "se3";
  static Shape ShapeOf(const pinocchio::SE3&) { return {4, 4}; }
  static void Flatten(const pinocchio::SE3& X, double* out) {
    Eigen::Map<Eigen::Matrix4d> H(out);
    H = X.toHomogeneousMatrix();
  }
  static void Unflatten(const double* in, pinocchio::SE3* X) {
    const Eigen::Map<const Eigen::Matrix4d> H(in);
    X->rotation() = H.topLeftCorner<3, 3>();
    X->translation() = H.topRightCorner<3, 1>();
  }
  static bool IsFinite(const pinocchio::SE3& X) {
    return X.rotation().allFinite() && X.translation().allFinite();
  }
};

}  // namespace marionette::graph
