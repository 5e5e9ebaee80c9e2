#include "marionette/walk/support_polygon.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace marionette::walk {

bool MeasuredZmp(const SoleWrench* w, int count, double ground_z, Eigen::Vector2d* zmp,
                 double min_force) {
  double fz = 0.0, mx = 0.0, my = 0.0;
  for (int i = 0; i < count; ++i) {
    if (w[i].force[2] < min_force) continue;
    const double h = w[i].origin[2] - ground_z;
    fz += w[i].force[2];
    mx += w[i].origin[0] * w[i].force[2] - w[i].torque[1] - h * w[i].force[0];
    my += w[i].origin[1] * w[i].force[2] + w[i].torque[0] - h * w[i].force[1];
  }
  if (fz <= 0.0) return false;
  *zmp << mx / fz, my / fz;
  return true;
}

namespace {

double Cross(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x();
}

}  // namespace

SupportPolygon MakeSupportPolygon(const FootPlacement* placements, int count,
                                  const SoleShape& sole) {
  std::array<Eigen::Vector2d, 8> points;
  int n = 0;
  for (int i = 0; i < std::min(count, 2); ++i) {
    const double c = std::cos(placements[i][3]), s = std::sin(placements[i][3]);
    for (const auto& [a, b] : {std::pair{1.0, 1.0}, {-1.0, 1.0}, {-1.0, -1.0}, {1.0, -1.0}}) {
      const double x = a * sole.half_length, y = b * sole.half_width;
      points[n++] = placements[i].head<2>() + Eigen::Vector2d(c * x - s * y, s * x + c * y);
    }
  }
  // Andrew's monotone chain, on the points sorted by (x, y): an insertion sort, as fast as any
  // for at most 8 points (and GCC 12 sees std::sort's introsort run past a runtime bound here).
  const auto before = [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  };
  for (int i = 1; i < n; ++i) {
    const Eigen::Vector2d p = points[i];
    int j = i;
    for (; j > 0 && before(p, points[j - 1]); --j) points[j] = points[j - 1];
    points[j] = p;
  }
  std::array<Eigen::Vector2d, 16> hull;
  int k = 0;
  for (int i = 0; i < n; ++i) {
    while (k >= 2 && Cross(hull[k - 2], hull[k - 1], points[i]) <= 0.0) --k;
    hull[k++] = points[i];
  }
  for (int i = n - 2, lower = k + 1; i >= 0; --i) {
    while (k >= lower && Cross(hull[k - 2], hull[k - 1], points[i]) <= 0.0) --k;
    hull[k++] = points[i];
  }
  SupportPolygon polygon;
  polygon.size = std::min(k - 1, 8);
  std::copy_n(hull.begin(), polygon.size, polygon.vertices.begin());
  return polygon;
}

double SignedMargin(const SupportPolygon& polygon, const Eigen::Vector2d& p) {
  bool inside = polygon.size >= 3;
  double distance = std::numeric_limits<double>::infinity();
  for (int i = 0; i < polygon.size; ++i) {
    const Eigen::Vector2d& a = polygon.vertices[i];
    const Eigen::Vector2d& b = polygon.vertices[(i + 1) % polygon.size];
    const Eigen::Vector2d ab = b - a;
    if (Cross(a, b, p) < 0.0) inside = false;  // right of a counter-clockwise edge
    const double s = std::clamp((p - a).dot(ab) / std::max(ab.squaredNorm(), 1e-18), 0.0, 1.0);
    distance = std::min(distance, (a + s * ab - p).norm());
  }
  return inside ? distance : -distance;
}

}  // namespace marionette::walk
