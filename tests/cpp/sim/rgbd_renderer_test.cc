// RgbdRenderer on a minimal scene (tests/data/perception/tag_box_scene.xml): a camera 1 m above
// a floor, looking straight down, and a box whose top face is 0.98 m from the camera.
#include "marionette/sim/rgbd_renderer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <thread>

namespace marionette::sim {
namespace {

constexpr char kScene[] = MARIONETTE_TEST_DATA_DIR "/perception/tag_box_scene.xml";

class RgbdRendererTest : public ::testing::Test {
 protected:
  void SetUp() override {
    char error[1000] = "";
    model_ = mj_loadXML(kScene, nullptr, error, sizeof(error));
    ASSERT_NE(model_, nullptr) << error;
    data_ = mj_makeData(model_);
    mj_forward(model_, data_);
  }
  void TearDown() override {
    mj_deleteData(data_);
    mj_deleteModel(model_);
  }
  mjModel* model_ = nullptr;
  mjData* data_ = nullptr;
};

TEST_F(RgbdRendererTest, IntrinsicsFollowFovy) {
  RgbdRenderer renderer(model_, "head", 640, 480);
  const PinholeIntrinsics& k = renderer.intrinsics();
  const double f = 240.0 / std::tan(22.5 * M_PI / 180.0);  // fovy = 45 deg in the scene
  EXPECT_NEAR(k.fx, f, 1e-9);
  EXPECT_NEAR(k.fy, f, 1e-9);
  EXPECT_DOUBLE_EQ(k.cx, 319.5);
  EXPECT_DOUBLE_EQ(k.cy, 239.5);
}

TEST_F(RgbdRendererTest, DepthIsMetricDistanceAlongTheOpticalAxis) {
  RgbdRenderer renderer(model_, "head", 640, 480);
  RgbdFrame frame;
  renderer.Render(*data_, &frame);
  ASSERT_EQ(frame.depth.size(), 640u * 480u);
  // The floor is face-on 1 m away: every floor pixel has z = 1 m, even at the image corners
  // where the ray is 28 deg off-axis (a range image would read 1.13 m there).
  for (int v : {0, 100, 479}) {
    for (int u : {0, 50, 639}) EXPECT_NEAR(frame.depth[v * 640 + u], 1.0, 1e-3) << u << "," << v;
  }
  // Top face of the box (centre at x = 0.15, y = 0.1 in the world, 2 cm high).
  const PinholeIntrinsics& k = renderer.intrinsics();
  const int u = static_cast<int>(std::lround(k.cx + k.fx * 0.15 / 0.98));
  const int v = static_cast<int>(std::lround(k.cy - k.fy * 0.10 / 0.98));  // world y is image up
  EXPECT_NEAR(frame.depth[v * 640 + u], 0.98, 1e-3);
}

TEST_F(RgbdRendererTest, CameraPoseIsTheOpticalFrame) {
  RgbdRenderer renderer(model_, "head", 640, 480);
  const Eigen::Isometry3d X_WC = renderer.CameraPose(*data_);
  EXPECT_TRUE(X_WC.translation().isApprox(Eigen::Vector3d(0, 0, 1), 1e-12));
  // Looking down: z_C = -z_W; x_C = x_W (right), y_C = -y_W (down in the image).
  EXPECT_TRUE(
      X_WC.linear().isApprox(Eigen::Vector3d(1, -1, -1).asDiagonal().toDenseMatrix(), 1e-12));
}

TEST_F(RgbdRendererTest, RendersTheSameFrameFromAnotherThread) {
  auto renderer = std::make_unique<RgbdRenderer>(model_, "head", 320, 240);
  RgbdFrame here, there;
  renderer->Render(*data_, &here);
  std::thread worker([&] { renderer->Render(*data_, &there); });
  worker.join();
  EXPECT_EQ(here.rgb, there.rgb);
  EXPECT_EQ(here.depth, there.depth);
}

TEST_F(RgbdRendererTest, LargerThanTheModelOffscreenBufferWorks) {
  RgbdRenderer renderer(model_, "head", 800, 600);  // the scene declares 640 x 480
  RgbdFrame frame;
  renderer.Render(*data_, &frame);
  EXPECT_NEAR(frame.depth[0], 1.0, 1e-3);
}

TEST_F(RgbdRendererTest, BadArgumentsAreRejectedWithTheReason) {
  try {
    RgbdRenderer renderer(model_, "nope", 640, 480);
    FAIL() << "expected RendererError";
  } catch (const RendererError& e) {
    EXPECT_NE(std::string(e.what()).find("cameras: head"), std::string::npos) << e.what();
  }
  EXPECT_THROW(RgbdRenderer(model_, "head", 0, 480), RendererError);
  EXPECT_THROW(RgbdRenderer(nullptr, "head", 640, 480), RendererError);
}

}  // namespace
}  // namespace marionette::sim
