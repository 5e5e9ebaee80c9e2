// The perception library against closed forms: exact pinhole projections, exact depth planes,
// an exactly placed tag image, and hand-eye pairs generated from a known transform.
#include <apriltag/apriltag.h>
#include <apriltag/common/image_u8.h>
#include <apriltag/tag36h11.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "marionette/perception/apriltag_detector.h"
#include "marionette/perception/hand_eye.h"
#include "marionette/perception/planar_pose.h"

namespace marionette::perception {
namespace {

const CameraIntrinsics kCamera{640, 480, 580.0, 580.0, 319.5, 239.5};

Eigen::Isometry3d Pose(const Eigen::Vector3d& rpy, const Eigen::Vector3d& p) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  X.translation() = p;
  return X;
}

double AngleBetween(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

std::vector<Eigen::Vector2d> Project(const std::vector<Eigen::Vector3d>& p_O,
                                     const Eigen::Isometry3d& X_CO) {
  std::vector<Eigen::Vector2d> uv;
  for (const auto& p : p_O) uv.push_back(kCamera.Project(X_CO * p));
  return uv;
}

std::vector<Eigen::Vector3d> Corners(double size) {
  const auto c = TagCorners(size);
  return {c.begin(), c.end()};
}

// Depth map of the plane z_O = 0 of X_CO (0 where the ray misses it or hits behind).
std::vector<float> PlaneDepth(const Eigen::Isometry3d& X_CO) {
  std::vector<float> depth(kCamera.width * kCamera.height, 0.0f);
  const Eigen::Vector3d n = X_CO.linear().col(2);
  const double d = n.dot(X_CO.translation());
  for (int v = 0; v < kCamera.height; ++v) {
    for (int u = 0; u < kCamera.width; ++u) {
      const Eigen::Vector3d ray((u - kCamera.cx) / kCamera.fx, (v - kCamera.cy) / kCamera.fy, 1.0);
      const double z = d / n.dot(ray);
      if (z > 0.0) depth[v * kCamera.width + u] = static_cast<float>(z);
    }
  }
  return depth;
}

TEST(TagCornersTest, CounterClockwiseFromBottomLeftInTheTagPlane) {
  const auto c = TagCorners(0.1);
  EXPECT_TRUE(c[0].isApprox(Eigen::Vector3d(-0.05, -0.05, 0)));
  EXPECT_TRUE(c[2].isApprox(Eigen::Vector3d(0.05, 0.05, 0)));
  // Counter-clockwise seen from +z (the viewer's side).
  EXPECT_GT((c[1] - c[0]).cross(c[2] - c[1]).z(), 0.0);
}

TEST(ReprojectionErrorTest, IsZeroAtTheTruthAndSumsSquaredPixels) {
  const Eigen::Isometry3d X = Pose({0.3, -0.2, 0.5}, {0.1, 0.0, 0.8});
  const auto p = Corners(0.08);
  auto uv = Project(p, X);
  EXPECT_NEAR(ReprojectionError(p, uv, kCamera, X), 0.0, 1e-18);
  uv[1].x() += 0.3;
  uv[3].y() -= 0.4;
  EXPECT_NEAR(ReprojectionError(p, uv, kCamera, X), 0.09 + 0.16, 1e-12);
  EXPECT_TRUE(std::isinf(ReprojectionError(p, uv, kCamera, Pose({0, 0, 0}, {0, 0, -1}))));
}

TEST(RefinePoseTest, ConvergesToTheTruthFromAPerturbedStartOnSeveralTags) {
  const Eigen::Isometry3d X_CO = Pose({2.6, 0.3, -0.4}, {-0.05, 0.04, 0.9});
  std::vector<Eigen::Vector3d> p_O;
  for (const Eigen::Vector3d& offset :
       {Eigen::Vector3d(-0.1, 0, 0), Eigen::Vector3d(0.1, 0, 0.02)}) {
    for (const auto& c : Corners(0.05)) p_O.push_back(c + offset);
  }
  const PoseEstimate e = RefinePose(p_O, Project(p_O, X_CO), kCamera,
                                    Pose({0.05, -0.05, 0.05}, {0.01, 0, 0.05}) * X_CO);
  ASSERT_TRUE(e.ok);
  EXPECT_LT((e.X_CO.translation() - X_CO.translation()).norm(), 1e-7);
  EXPECT_LT(AngleBetween(e.X_CO, X_CO), 1e-7);
  EXPECT_EQ(e.num_points, 8);
}

TEST(RefinePoseTest, RejectsTooFewOrMismatchedPoints) {
  const auto p = Corners(0.1);
  EXPECT_THROW(
      RefinePose({p[0], p[1], p[2]}, {{1, 1}, {2, 2}, {3, 3}}, kCamera, Pose({0, 0, 0}, {0, 0, 1})),
      PerceptionError);
  EXPECT_THROW(RefinePose(p, {{1, 1}}, kCamera, Pose({0, 0, 0}, {0, 0, 1})), PerceptionError);
  CameraIntrinsics bad = kCamera;
  bad.fx = std::nan("");
  EXPECT_THROW(
      RefinePose(p, Project(p, Pose({M_PI, 0, 0}, {0, 0, 1})), bad, Pose({0, 0, 0}, {0, 0, 1})),
      PerceptionError);
}

TEST(PoseFromRgbdTest, ExactPlaneGivesTheTruth) {
  const Eigen::Isometry3d X_CT = Pose({M_PI + 0.4, 0.2, 0.3}, {0.05, -0.02, 0.7});
  const auto p = Corners(0.1);
  const std::vector<float> depth = PlaneDepth(X_CT);
  const PoseEstimate e = PoseFromRgbd(depth.data(), kCamera, Project(p, X_CT), p);
  ASSERT_TRUE(e.ok);
  EXPECT_LT((e.X_CO.translation() - X_CT.translation()).norm(), 1e-4);
  EXPECT_LT(AngleBetween(e.X_CO, X_CT), 1e-3);
  EXPECT_GT(e.confidence, 0.9);
  std::vector<float> empty(depth.size(), 0.0f);
  EXPECT_FALSE(PoseFromRgbd(empty.data(), kCamera, Project(p, X_CT), p).ok);
}

TEST(RefinePoseRgbdTest, DepthPullsTheMirrorHypothesisBackToTheTruth) {
  // Small tag, far, slightly tilted: its corners are explained by two tilts. Starting from the
  // mirror tilt, the image-only refinement stays there; with depth it comes back to the truth.
  const Eigen::Isometry3d X_CT = Pose({M_PI + 0.2, 0.1, 0.5}, {0.02, 0.01, 1.5});
  const Eigen::Isometry3d mirror = Pose({M_PI - 0.2, -0.1, 0.5}, {0.02, 0.01, 1.5});
  const auto p = Corners(0.06);
  const auto uv = Project(p, X_CT);
  const PoseEstimate image_only = RefinePose(p, uv, kCamera, mirror);
  ASSERT_TRUE(image_only.ok);
  EXPECT_GT(AngleBetween(image_only.X_CO, X_CT), 0.2);  // a second local minimum
  EXPECT_LT(image_only.reprojection_error, 0.05);       // that fits the corners within noise
  const std::vector<float> depth = PlaneDepth(X_CT);
  const PoseEstimate fused =
      RefinePoseRgbd(p, uv, {{uv, Eigen::Vector3d::UnitZ(), 0.0}}, depth.data(), kCamera, mirror);
  ASSERT_TRUE(fused.ok);
  EXPECT_LT(AngleBetween(fused.X_CO, X_CT), 1e-4);
  EXPECT_LT((fused.X_CO.translation() - X_CT.translation()).norm(), 1e-5);
  EXPECT_GT(fused.num_points, 4 + 100);
}

TEST(RefinePoseRgbdTest, PlaneOffsetsInTheObjectFrameAreHonoured) {
  // Two faces of a body at different heights: z_O = 0 and z_O = 0.03 (a step).
  const Eigen::Isometry3d X_CO = Pose({M_PI + 0.3, -0.2, 0.1}, {0.0, 0.0, 0.9});
  std::vector<Eigen::Vector3d> p_O;
  for (const auto& c : Corners(0.05)) p_O.push_back(c + Eigen::Vector3d(-0.06, 0, 0));
  for (const auto& c : Corners(0.05)) p_O.push_back(c + Eigen::Vector3d(0.06, 0, 0.03));
  const auto uv = Project(p_O, X_CO);
  std::vector<float> depth = PlaneDepth(X_CO);
  const std::vector<float> raised = PlaneDepth(X_CO * Pose({0, 0, 0}, {0, 0, 0.03}));
  for (size_t i = 0; i < depth.size(); ++i) {  // right half of the image: the raised face
    if (static_cast<int>(i % kCamera.width) > kCamera.Project(X_CO.translation()).x()) {
      depth[i] = raised[i];
    }
  }
  const std::vector<DepthPlane> planes = {
      {{uv[0], uv[1], uv[2], uv[3]}, Eigen::Vector3d::UnitZ(), 0.0},
      {{uv[4], uv[5], uv[6], uv[7]}, Eigen::Vector3d::UnitZ(), 0.03}};
  const PoseEstimate e = RefinePoseRgbd(p_O, uv, planes, depth.data(), kCamera,
                                        Pose({0.03, 0.02, 0}, {0.005, 0, 0.01}) * X_CO);
  ASSERT_TRUE(e.ok);
  EXPECT_LT(AngleBetween(e.X_CO, X_CO), 1e-4);
  EXPECT_LT((e.X_CO.translation() - X_CO.translation()).norm(), 1e-5);
}

// A face-on tag36h11 drawn with whole pixels: `scale` pixels per cell, top-left cell at
// (u0, v0). Its black square's corners lie on pixel edges, at known half-integer coordinates.
std::vector<std::uint8_t> DrawTag(int id, int scale, int u0, int v0) {
  apriltag_family_t* family = tag36h11_create();
  image_u8_t* tag = apriltag_to_image(family, id);
  std::vector<std::uint8_t> image(kCamera.width * kCamera.height, 128);
  for (int r = 0; r < tag->height * scale; ++r) {
    for (int c = 0; c < tag->width * scale; ++c) {
      image[(v0 + r) * kCamera.width + u0 + c] = tag->buf[(r / scale) * tag->stride + c / scale];
    }
  }
  image_u8_destroy(tag);
  tag36h11_destroy(family);
  return image;
}

TEST(AprilTagDetectorTest, FindsAFaceOnTagWithCornersOnPixelEdges) {
  const int scale = 6, u0 = 280, v0 = 200;
  const std::vector<std::uint8_t> image = DrawTag(42, scale, u0, v0);
  AprilTagDetector detector;
  const double size = 0.08;
  const auto detections = detector.Detect(image.data(), 640, 480, kCamera, {0.0, {{42, size}}});
  ASSERT_EQ(detections.size(), 1u);
  const TagDetection& d = detections[0];
  EXPECT_EQ(d.id, 42);
  ASSERT_TRUE(d.has_pose);
  // Black square: cells 1..8 of 10, i.e. pixels [u0 + 6, u0 + 54) -> edges at u0 + 5.5 and
  // u0 + 53.5 in integer-centre coordinates. Corner 0 is bottom-left, then counter-clockwise.
  const double left = u0 + scale - 0.5, right = u0 + 9 * scale - 0.5;
  const double top = v0 + scale - 0.5, bottom = v0 + 9 * scale - 0.5;
  const Eigen::Vector2d expected[4] = {{left, bottom}, {right, bottom}, {right, top}, {left, top}};
  // AprilTag places hard (un-antialiased) edges 0.125 px inwards (AprilRobotics/apriltag#334):
  // within 0.2 px, and far from the 0.7 px a missed half-pixel convention shift would give.
  for (int i = 0; i < 4; ++i) EXPECT_LT((d.corners[i] - expected[i]).norm(), 0.2) << i;
  // Face-on: z_T towards the camera, and the distance from the black square's width.
  const Eigen::Isometry3d& X = d.hypotheses[0].X_CT;
  EXPECT_LT(X.linear().col(2).dot(Eigen::Vector3d::UnitZ()), -0.99);
  EXPECT_NEAR(X.translation().z(), kCamera.fx * size / (right - left), 0.01);
  EXPECT_LE(d.hypotheses[0].reprojection_error, d.hypotheses[1].reprojection_error);
}

TEST(AprilTagDetectorTest, TagsWithoutSizeHaveNoPoseAndBadImagesThrow) {
  const std::vector<std::uint8_t> image = DrawTag(3, 5, 100, 100);
  AprilTagDetector detector;
  const auto detections = detector.Detect(image.data(), 640, 480, kCamera, {});
  ASSERT_EQ(detections.size(), 1u);
  EXPECT_FALSE(detections[0].has_pose);
  EXPECT_THROW(detector.Detect(image.data(), 320, 240, kCamera, {}), PerceptionError);
  EXPECT_THROW(detector.Detect(nullptr, 640, 480, kCamera, {}), PerceptionError);
  EXPECT_THROW(AprilTagDetector({0.5f}), PerceptionError);
}

TEST(NoiseEstimateTest, MatchesTheStandardDeviationOfAddedNoiseOverATag) {
  // Closed form: i.i.d. Gaussian noise of s grey levels, rounded to integers, over an image
  // with a tag's edges (a minority of pixels) must read as s.
  for (const double sigma : {0.0, 1.0, 2.0, 5.0}) {
    std::vector<std::uint8_t> image = DrawTag(3, 5, 100, 100);
    std::mt19937 rng(static_cast<unsigned>(10 * sigma));
    std::normal_distribution<double> noise(0.0, sigma);
    for (std::uint8_t& p : image) {
      p = static_cast<std::uint8_t>(std::clamp(std::lround(p * 0.8 + 25.0 + noise(rng)), 0L, 255L));
    }
    const double estimate = EstimateNoiseSigma(image.data(), 640, 480, 640);
    EXPECT_NEAR(estimate, sigma, 0.05 + 0.05 * sigma) << "sigma " << sigma;
    EXPECT_EQ(BlurForNoise(estimate) > 0.0f, sigma > 0.5) << "sigma " << sigma;
  }
}

TEST(AprilTagDetectorTest, ARegionAroundATagFindsItWhereTheWholeImageDoes) {
  const std::vector<std::uint8_t> image = DrawTag(3, 5, 200, 150);
  AprilTagDetector detector;
  TagSizes sizes{0.1, {}};
  const auto whole = detector.Detect(image.data(), 640, 480, kCamera, sizes);
  ASSERT_EQ(whole.size(), 1u);
  EXPECT_EQ(detector.last_stats().pixels_searched, 640L * 480L);
  // Two overlapping boxes around the tag (merged: found once) and one elsewhere.
  const std::vector<PixelBox> boxes{{150, 100, 300, 260}, {180, 120, 330, 290}, {500, 10, 600, 90}};
  const auto regional = detector.Detect(image.data(), 640, 480, kCamera, sizes, boxes);
  ASSERT_EQ(regional.size(), 1u);
  // Started on the 4-pixel tile grid: 150 -> 148, 10 -> 8.
  EXPECT_EQ(detector.last_stats().pixels_searched, 182L * 190L + 100L * 82L);
  // Within a tenth of a pixel here, not bit-exact: this drawn tag's edges lie exactly on pixel
  // edges, a degenerate step where the quad fit's start differs with the box; on rendered
  // (antialiased) tags the two searches agree to 1e-4 px
  // (tests/python/perception/test_tracking.py).
  for (int c = 0; c < 4; ++c) {
    EXPECT_LT((regional[0].corners[c] - whole[0].corners[c]).norm(), 0.1);
  }
  const Eigen::Isometry3d& X_regional = regional[0].hypotheses[0].X_CT;
  const Eigen::Isometry3d& X_whole = whole[0].hypotheses[0].X_CT;
  EXPECT_LT((X_regional.translation() - X_whole.translation()).norm(), 1e-3);
  EXPECT_LT(Eigen::AngleAxisd(X_regional.linear().transpose() * X_whole.linear()).angle(), 0.01);
  // A box that holds only part of the tag finds nothing; one outside the image is dropped.
  EXPECT_TRUE(
      detector.Detect(image.data(), 640, 480, kCamera, sizes, {{150, 100, 230, 180}}).empty());
  EXPECT_TRUE(detector.Detect(image.data(), 640, 480, kCamera, sizes, {{700, 0, 800, 50}}).empty());
}

TEST(MergeBoxesTest, ClipsDropsAndMergesUntilNoneIntersect) {
  // a and b intersect; their union then intersects c; d touches c's edge only; e starts on
  // the grid of 4 once aligned.
  const std::vector<PixelBox> aligned = MergeBoxes({{7, 13, 20, 20}}, 80, 50, 4);
  ASSERT_EQ(aligned.size(), 1u);
  EXPECT_EQ(aligned[0].u0, 4);
  EXPECT_EQ(aligned[0].v0, 12);
  const std::vector<PixelBox> merged = MergeBoxes({{-10, -10, 20, 20},
                                                   {10, 10, 40, 40},
                                                   {35, 0, 60, 15},
                                                   {60, 0, 70, 10},
                                                   {100, 100, 120, 120},
                                                   {5, 5, 5, 9}},
                                                  80, 50);
  ASSERT_EQ(merged.size(), 2u);
  EXPECT_EQ(merged[0].u0, 0);
  EXPECT_EQ(merged[0].v0, 0);
  EXPECT_EQ(merged[0].u1, 60);
  EXPECT_EQ(merged[0].v1, 40);
  EXPECT_EQ(merged[1].u0, 60);
  EXPECT_EQ(merged[1].u1, 70);
}

TEST(HandEyeTest, RecoversTheCameraMountFromNoiselessPairs) {
  const Eigen::Isometry3d X_EC = Pose({0.1, -1.4, 0.3}, {0.07, 0.03, 0.14});
  const Eigen::Isometry3d X_RT = Pose({0.0, 0.2, 1.0}, {0.8, 0.1, 0.3});
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> angle(-0.6, 0.6), offset(-0.2, 0.2);
  std::vector<Eigen::Isometry3d> X_RE, X_CT;
  for (int i = 0; i < 12; ++i) {
    X_RE.push_back(Pose({angle(rng), angle(rng), angle(rng)},
                        {0.4 + offset(rng), offset(rng), 0.8 + offset(rng)}));
    X_CT.push_back(X_EC.inverse() * X_RE.back().inverse() * X_RT);
  }
  const HandEyeResult r = CalibrateHandEye(X_RE, X_CT);
  EXPECT_LT((r.X_EC.translation() - X_EC.translation()).norm(), 1e-6);
  EXPECT_LT(AngleBetween(r.X_EC, X_EC), 1e-6);
  EXPECT_LT((r.X_RT.translation() - X_RT.translation()).norm(), 1e-6);
  EXPECT_LT(r.rms_position, 1e-6);
  EXPECT_THROW(CalibrateHandEye({X_RE[0], X_RE[1]}, {X_CT[0], X_CT[1]}), PerceptionError);
  EXPECT_THROW(CalibrateHandEye(X_RE, {X_CT[0]}), PerceptionError);
}

}  // namespace
}  // namespace marionette::perception
