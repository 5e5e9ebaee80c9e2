// Features: every Jacobian against central finite differences on the configuration manifold
// (q ⊕ h e_i with Pinocchio's integrate), every drift against finite differences in time of a
// moving reference, on TALOS (free-flyer), UR10 (fixed base) and TIAGo (planar base); errors
// against closed forms; constructors reject bad arguments with a message naming the culprit.
#include <gtest/gtest.h>

#include <random>

#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>

#include "example_robots.h"
#include "marionette/sot/feature_com.h"
#include "marionette/sot/feature_gaze.h"
#include "marionette/sot/feature_pbvs.h"
#include "marionette/sot/feature_position.h"
#include "marionette/sot/feature_posture.h"
#include "marionette/sot/feature_relative_se3.h"
#include "marionette/sot/feature_se3.h"
#include "marionette/sot/joint_limits.h"
#include "marionette/sot/robot_model.h"

namespace marionette::sot {
namespace {

ModelPtr Ur10() {
  return LoadModel(ExampleRobotDataDir() + "/ur_description/urdf/ur10_robot.urdf",
                   BaseJoint::kFixed);
}
ModelPtr Tiago() {
  return LoadModel(ExampleRobotDataDir() + "/tiago_description/robots/tiago.urdf",
                   BaseJoint::kPlanar);
}

// A configuration near `center` (or the neutral one), away from singular zero angles.
Eigen::VectorXd RandomConfiguration(const pinocchio::Model& model, unsigned seed,
                                    const Eigen::VectorXd* center = nullptr) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-0.4, 0.4);
  Eigen::VectorXd v(model.nv);
  for (int i = 0; i < model.nv; ++i) v[i] = u(rng);
  return pinocchio::integrate(model, center ? *center : pinocchio::neutral(model), v);
}

// Evaluates a feature at q with a fresh tick (its kinematics input set to the pass at q).
// Ticks come from one counter: outputs are cached per tick index.
class Probe {
 public:
  explicit Probe(Feature& f) : f_(f), kinematics_(f.model()) {}
  const FeatureTerms& At(const Eigen::VectorXd& q) {
    kinematics_.Compute(q);
    f_.kinematics_input().SetValue(kinematics_);
    static int64_t index = 0;
    return f_.terms_output().Eval(graph::Tick{++index});
  }

 private:
  Feature& f_;
  Kinematics kinematics_;
};

// Central differences of the error along each tangent direction at q.
Eigen::MatrixXd FiniteDifferenceJacobian(Feature& f, const Eigen::VectorXd& q, double h = 1e-6) {
  Probe probe(f);
  const pinocchio::Model& model = *f.model();
  Eigen::MatrixXd J(f.dimension(), model.nv);
  for (int i = 0; i < model.nv; ++i) {
    Eigen::VectorXd dv = Eigen::VectorXd::Zero(model.nv);
    dv[i] = h;
    const Eigen::VectorXd ep = probe.At(pinocchio::integrate(model, q, dv)).error;
    const Eigen::VectorXd em = probe.At(pinocchio::integrate(model, q, -dv)).error;
    J.col(i) = (ep - em) / (2 * h);
  }
  return J;
}

void ExpectJacobianMatchesFiniteDifferences(Feature& f, const Eigen::VectorXd& q,
                                            double tol = 1e-6) {
  Probe probe(f);
  const Eigen::MatrixXd J = probe.At(q).jacobian;
  const Eigen::MatrixXd J_fd = FiniteDifferenceJacobian(f, q);
  ASSERT_EQ(J.rows(), f.dimension());
  EXPECT_GT(J.norm(), 1e-3) << f.name() << ": a zero Jacobian proves nothing";
  EXPECT_LT((J - J_fd).cwiseAbs().maxCoeff(), tol * std::max(1.0, J.cwiseAbs().maxCoeff()))
      << f.name() << "\nJ =\n"
      << J << "\nJ_fd =\n"
      << J_fd;
}

pinocchio::SE3 SomePose(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const Eigen::Vector3d w(u(rng), u(rng), u(rng));
  return pinocchio::SE3(pinocchio::exp3(w), Eigen::Vector3d(u(rng), u(rng), 0.5 + u(rng)));
}

// Moves a pose by a world-axes twist (v: origin velocity, w: angular) for time h.
pinocchio::SE3 MoveInWorldAxes(const pinocchio::SE3& X, const Eigen::VectorXd& twist, double h) {
  return pinocchio::SE3(pinocchio::exp3(Eigen::Vector3d(h * twist.tail<3>())) * X.rotation(),
                        X.translation() + h * twist.head<3>());
}

class FeatureTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { talos_ = LoadTalos(); }
  static ModelPtr talos_;
  Eigen::VectorXd HalfSitting() const { return talos_->referenceConfigurations.at("half_sitting"); }
};
ModelPtr FeatureTest::talos_;

TEST_F(FeatureTest, Se3JacobianMatchesFiniteDifferencesOnTalos) {
  FeatureSE3 f("hand", talos_, "gripper_right_base_link");
  f.reference_input().SetValue(SomePose(1));
  const Eigen::VectorXd q0 = HalfSitting();
  for (unsigned seed : {1u, 2u, 3u}) {
    ExpectJacobianMatchesFiniteDifferences(f, RandomConfiguration(*talos_, seed, &q0));
  }
}

TEST_F(FeatureTest, Se3ErrorIsLogOfReferenceToFramePose) {
  FeatureSE3 f("hand", talos_, "gripper_right_base_link");
  Probe probe(f);
  const Eigen::VectorXd q = HalfSitting();
  Kinematics k(talos_);
  k.Compute(q);
  const pinocchio::SE3 X_WF = k.placement(MakeFrameRef(*talos_, "gripper_right_base_link", "test"));
  // Reference = frame pose moved by a known local displacement: e = -that displacement.
  const Eigen::Matrix<double, 6, 1> xi =
      (Eigen::Matrix<double, 6, 1>() << 0.1, -0.2, 0.05, 0.2, 0.1, -0.3).finished();
  f.reference_input().SetValue(X_WF * pinocchio::exp6(pinocchio::Motion(xi)));
  EXPECT_LT((probe.At(q).error + xi).norm(), 1e-12);
  f.reference_input().SetValue(X_WF);
  EXPECT_LT(probe.At(q).error.norm(), 1e-12);
}

TEST_F(FeatureTest, Se3DriftMatchesFiniteDifferencesOfAMovingReference) {
  FeatureSE3 f("hand", talos_, "gripper_right_base_link");
  Probe probe(f);
  const Eigen::VectorXd q = HalfSitting();
  const pinocchio::SE3 X_WD = SomePose(4);
  Eigen::VectorXd twist(6);
  twist << 0.3, -0.1, 0.2, 0.5, -0.4, 0.7;
  f.reference_velocity_input().SetValue(twist);
  f.reference_input().SetValue(X_WD);
  const Eigen::VectorXd drift = probe.At(q).drift;
  const double h = 1e-6;
  f.reference_input().SetValue(MoveInWorldAxes(X_WD, twist, h));
  const Eigen::VectorXd ep = probe.At(q).error;
  f.reference_input().SetValue(MoveInWorldAxes(X_WD, twist, -h));
  const Eigen::VectorXd em = probe.At(q).error;
  EXPECT_LT((drift - (ep - em) / (2 * h)).norm(), 1e-6) << drift.transpose();
}

TEST_F(FeatureTest, MaskKeepsSelectedRows) {
  FeatureSE3 full("full", talos_, "left_sole_link");
  FeatureSE3 masked("masked", talos_, "left_sole_link", {true, false, true, false, false, true});
  full.reference_input().SetValue(SomePose(5));
  masked.reference_input().SetValue(SomePose(5));
  Probe pf(full), pm(masked);
  const Eigen::VectorXd q = HalfSitting();
  const FeatureTerms& tf = pf.At(q);
  const FeatureTerms& tm = pm.At(q);
  ASSERT_EQ(masked.dimension(), 3);
  const int rows[] = {0, 2, 5};
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(tm.error[i], tf.error[rows[i]]);
    EXPECT_EQ((tm.jacobian.row(i) - tf.jacobian.row(rows[i])).norm(), 0.0);
  }
  ExpectJacobianMatchesFiniteDifferences(masked, q);
}

TEST_F(FeatureTest, RelativeSe3JacobianMatchesFiniteDifferences) {
  FeatureRelativeSE3 f("handover", talos_, "gripper_left_base_link", "gripper_right_base_link");
  f.reference_input().SetValue(SomePose(6));
  ExpectJacobianMatchesFiniteDifferences(f, HalfSitting());
  ExpectJacobianMatchesFiniteDifferences(
      f, pinocchio::integrate(*talos_, HalfSitting(), Eigen::VectorXd::Constant(talos_->nv, 0.1)));
}

TEST_F(FeatureTest, RelativeSe3IgnoresJointsMovingBothFrames) {
  // The free-flyer and torso move both grippers rigidly: no relative motion.
  FeatureRelativeSE3 f("handover", talos_, "gripper_left_base_link", "gripper_right_base_link");
  Probe probe(f);
  const Eigen::MatrixXd J = probe.At(HalfSitting()).jacobian;
  EXPECT_LT(J.leftCols(6).norm(), 1e-12);
  const int torso = talos_->idx_vs[talos_->getJointId("torso_1_joint")];
  EXPECT_LT(J.middleCols(torso, 2).norm(), 1e-12);
}

TEST_F(FeatureTest, RelativeSe3DriftMatchesFiniteDifferences) {
  FeatureRelativeSE3 f("handover", talos_, "gripper_left_base_link", "gripper_right_base_link");
  Probe probe(f);
  const pinocchio::SE3 X_BD = SomePose(7);
  Eigen::VectorXd twist(6);
  twist << -0.2, 0.4, 0.1, 0.3, 0.2, -0.5;
  f.reference_velocity_input().SetValue(twist);
  f.reference_input().SetValue(X_BD);
  const Eigen::VectorXd drift = probe.At(HalfSitting()).drift;
  const double h = 1e-6;
  f.reference_input().SetValue(MoveInWorldAxes(X_BD, twist, h));
  const Eigen::VectorXd ep = probe.At(HalfSitting()).error;
  f.reference_input().SetValue(MoveInWorldAxes(X_BD, twist, -h));
  const Eigen::VectorXd em = probe.At(HalfSitting()).error;
  EXPECT_LT((drift - (ep - em) / (2 * h)).norm(), 1e-6);
}

TEST_F(FeatureTest, PositionAndComJacobiansMatchFiniteDifferences) {
  FeaturePosition p("tip", talos_, "gripper_left_base_link");
  p.reference_input().SetValue(Eigen::Vector3d(0.3, 0.2, 1.0));
  FeatureCom com("com", talos_, {true, true, false});
  const Eigen::VectorXd q =
      pinocchio::integrate(*talos_, HalfSitting(), Eigen::VectorXd::Constant(talos_->nv, -0.05));
  ExpectJacobianMatchesFiniteDifferences(p, q);
  ExpectJacobianMatchesFiniteDifferences(com, q);
  Probe probe(p);
  Kinematics k(talos_);
  k.Compute(q);
  EXPECT_LT((probe.At(q).error -
             (k.placement(MakeFrameRef(*talos_, "gripper_left_base_link", "t")).translation() -
              Eigen::Vector3d(0.3, 0.2, 1.0)))
                .norm(),
            1e-14);
}

TEST_F(FeatureTest, PostureErrorIsJointDifferenceAndJacobianSelectsJoints) {
  FeaturePosture f("posture", talos_, {"arm_left_4_joint", "head_2_joint"});
  const Eigen::VectorXd q0 = HalfSitting();
  f.reference_input().SetValue(q0);
  Probe probe(f);
  Eigen::VectorXd q = q0;
  const int i1 = talos_->idx_qs[talos_->getJointId("arm_left_4_joint")];
  const int i2 = talos_->idx_qs[talos_->getJointId("head_2_joint")];
  q[i1] += 0.3;
  q[i2] -= 0.1;
  const FeatureTerms& t = probe.At(q);
  EXPECT_NEAR(t.error[0], 0.3, 1e-15);
  EXPECT_NEAR(t.error[1], -0.1, 1e-15);
  EXPECT_EQ(f.unit_columns()[0], talos_->idx_vs[talos_->getJointId("arm_left_4_joint")]);
  ExpectJacobianMatchesFiniteDifferences(f, q);
}

TEST_F(FeatureTest, GazeJacobianAndDriftMatchFiniteDifferences) {
  FeatureGaze f("gaze", talos_, "rgbd_rgb_optical_frame");
  Probe probe(f);
  const Eigen::VectorXd q = HalfSitting();
  Kinematics k(talos_);
  k.Compute(q);
  const pinocchio::SE3& X_WC = k.placement(MakeFrameRef(*talos_, "rgbd_rgb_optical_frame", "t"));
  const Eigen::Vector3d P = X_WC.act(Eigen::Vector3d(0.2, -0.1, 1.5));  // in front of the camera
  f.target_input().SetValue(P);
  EXPECT_LT((probe.At(q).error - Eigen::Vector2d(0.2 / 1.5, -0.1 / 1.5)).norm(), 1e-12);
  ExpectJacobianMatchesFiniteDifferences(f, q);
  const Eigen::Vector3d Pdot(0.1, 0.3, -0.2);
  f.target_velocity_input().SetValue(Pdot);
  const Eigen::VectorXd drift = probe.At(q).drift;
  const double h = 1e-6;
  f.target_input().SetValue(P + h * Pdot);
  const Eigen::VectorXd ep = probe.At(q).error;
  f.target_input().SetValue(P - h * Pdot);
  const Eigen::VectorXd em = probe.At(q).error;
  EXPECT_LT((drift - (ep - em) / (2 * h)).norm(), 1e-7);
}

TEST_F(FeatureTest, PbvsErrorUsesOnlyMeasuredPosesAndItsJacobianMatches) {
  // The camera's pose estimate is wrong by X_err; measurements are consistent with it. The
  // error (eq. 5.3) is the gripper-to-handle error whatever X_err is.
  FeaturePbvs f("pbvs", talos_, "gripper_right_base_link");
  Probe probe(f);
  const pinocchio::SE3 X_err = SomePose(8);  // estimated-camera <- world
  const pinocchio::SE3 X_WO = SomePose(9);   // object (handle) in world
  const pinocchio::SE3 X_OG = SomePose(10);  // desired grasp in object frame
  f.grasp_input().SetValue(X_OG);
  f.measured_object_input().SetValue(X_err * X_WO);
  const auto gripper = MakeFrameRef(*talos_, "gripper_right_base_link", "t");
  Kinematics k(talos_);
  auto at = [&](const Eigen::VectorXd& q) -> const FeatureTerms& {
    k.Compute(q);
    f.measured_gripper_input().SetValue(X_err * k.placement(gripper));
    return probe.At(q);
  };
  const Eigen::VectorXd q = HalfSitting();
  const Eigen::VectorXd e = at(q).error;
  const pinocchio::SE3 truth = (X_WO * X_OG).actInv(k.placement(gripper));
  EXPECT_LT((e - pinocchio::log6(truth).toVector()).norm(), 1e-12);
  const Eigen::MatrixXd J = at(q).jacobian;
  Eigen::MatrixXd J_fd(6, talos_->nv);
  const double h = 1e-6;
  for (int i = 0; i < talos_->nv; ++i) {
    Eigen::VectorXd dv = Eigen::VectorXd::Zero(talos_->nv);
    dv[i] = h;
    const Eigen::VectorXd ep = at(pinocchio::integrate(*talos_, q, dv)).error;
    const Eigen::VectorXd em = at(pinocchio::integrate(*talos_, q, -dv)).error;
    J_fd.col(i) = (ep - em) / (2 * h);
  }
  EXPECT_LT((J - J_fd).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(FeatureRobotsTest, FixedBaseUr10JacobiansMatchFiniteDifferences) {
  const ModelPtr ur10 = Ur10();
  EXPECT_EQ(ur10->nv, 6);
  FeatureSE3 tool("tool", ur10, "tool0");
  tool.reference_input().SetValue(SomePose(11));
  FeaturePosition wrist("wrist", ur10, "wrist_2_link");
  const Eigen::VectorXd q = RandomConfiguration(*ur10, 12);
  ExpectJacobianMatchesFiniteDifferences(tool, q);
  ExpectJacobianMatchesFiniteDifferences(wrist, q);
}

TEST(FeatureRobotsTest, PlanarBaseTiagoJacobiansMatchFiniteDifferences) {
  const ModelPtr tiago = Tiago();
  FeatureSE3 tool("tool", tiago, "arm_tool_link");
  tool.reference_input().SetValue(SomePose(13));
  FeatureCom com("com", tiago);
  FeaturePosture posture("posture", tiago);  // includes the continuous wheel joints
  posture.reference_input().SetValue(RandomConfiguration(*tiago, 14));
  const Eigen::VectorXd q = RandomConfiguration(*tiago, 15);
  ExpectJacobianMatchesFiniteDifferences(tool, q);
  ExpectJacobianMatchesFiniteDifferences(com, q);
  ExpectJacobianMatchesFiniteDifferences(posture, q);
}

TEST_F(FeatureTest, RobotModelEntityComputesTheKinematicsOfItsInput) {
  RobotModel robot("robot", talos_);
  const Eigen::VectorXd q = HalfSitting();
  robot.configuration_input().SetValue(q);
  const Kinematics& k = robot.kinematics_output().Eval(graph::Tick{1});
  pinocchio::Data data(*talos_);
  EXPECT_LT((k.com() - pinocchio::centerOfMass(*talos_, data, q)).norm(), 1e-14);
  EXPECT_EQ((k.q() - q).norm(), 0.0);
}

TEST_F(FeatureTest, ConstructorsRejectBadArgumentsWithPreciseMessages) {
  try {
    FeatureSE3 f("hand", talos_, "gripper_rigth_base_link");
    FAIL() << "no exception";
  } catch (const SotError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown frame 'gripper_rigth_base_link'"),
              std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("FeatureSE3 'hand'"), std::string::npos) << e.what();
  }
  EXPECT_THROW(FeatureSE3("m", talos_, "left_sole_link", {true, false}), SotError);
  EXPECT_THROW(FeatureSE3("m", talos_, "left_sole_link", Mask(6, false)), SotError);
  EXPECT_THROW(FeaturePosture("p", talos_, {"root_joint"}), SotError);
  EXPECT_THROW(FeaturePosture("p", talos_, {"no_such_joint"}), SotError);
  EXPECT_THROW(FeatureRelativeSE3("r", talos_, "left_sole_link", "left_sole_link"), SotError);
  EXPECT_THROW(LoadModel("/nonexistent.urdf", BaseJoint::kFixed), SotError);
  EXPECT_THROW(ParseBaseJoint("floating"), SotError);
  EXPECT_THROW(FeatureHeldVelocities("h", talos_, {}), SotError);
  EXPECT_THROW(FeatureHeldVelocities("h", talos_, {0, 0}), SotError);
  EXPECT_THROW(FeatureHeldVelocities("h", talos_, {talos_->nv}), SotError);
  EXPECT_THROW(FeatureHeldVelocities("h", talos_, {-1}), SotError);
}

TEST(FeatureRobotsTest, HeldVelocitiesAreUnitRowsWithZeroErrorAndAZeroRateBox) {
  const ModelPtr tiago = Tiago();
  FeatureHeldVelocities held("held", tiago, {0, 1, 2});
  const FeatureTerms& f = Probe(held).At(RandomConfiguration(*tiago, 16));
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(3, tiago->nv);
  expected.leftCols(3).setIdentity();
  EXPECT_EQ(f.jacobian, expected);
  EXPECT_EQ(f.error, Eigen::Vector3d::Zero());
  EXPECT_EQ(held.unit_columns(), (std::vector<int>{0, 1, 2}));
  const TaskBounds b = HeldVelocityBounds(held);
  EXPECT_EQ(b.rate_lower, Eigen::Vector3d::Zero());
  EXPECT_EQ(b.rate_upper, Eigen::Vector3d::Zero());
}

}  // namespace
}  // namespace marionette::sot
