// marionette._core.planning.Projector: the Newton-Raphson projector of cpp/src/planning, used by
// marionette.planning.projector_cpp (which compiles the specs from a Python Projector).
// Bindings only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <stdexcept>
#include <string>

#include "marionette/planning/leaf_planner.h"
#include "marionette/planning/path_validator.h"
#include "marionette/planning/projector.h"

namespace py = pybind11;

namespace marionette::bindings {

namespace {

pinocchio::SE3 Pose(const Eigen::Matrix4d& M) {
  return pinocchio::SE3(Eigen::Matrix3d(M.topLeftCorner<3, 3>()),
                        Eigen::Vector3d(M.topRightCorner<3, 1>()));
}

std::vector<pinocchio::SE3> Poses(const std::vector<Eigen::Matrix4d>& Ms) {
  std::vector<pinocchio::SE3> out;
  for (const auto& M : Ms) out.push_back(Pose(M));
  return out;
}

planning::ImplicitSpec::Kind ImplicitKind(const std::string& k) {
  using K = planning::ImplicitSpec::Kind;
  if (k == "relative") return K::kRelative;
  if (k == "placement") return K::kPlacement;
  if (k == "complement") return K::kComplement;
  if (k == "locked") return K::kLocked;
  if (k == "com") return K::kCom;
  throw std::invalid_argument("implicit constraint kind '" + k +
                              "' is not supported (relative placement complement locked com)");
}

planning::LineSearchSpec::Kind LineSearchKind(const std::string& k) {
  using K = planning::LineSearchSpec::Kind;
  if (k == "fixed_sequence") return K::kFixedSequence;
  if (k == "error_norm") return K::kErrorNorm;
  if (k == "constant") return K::kConstant;
  throw std::invalid_argument("line search kind '" + k +
                              "' is not supported (fixed_sequence error_norm constant)");
}

}  // namespace

void RegisterPlanningProjector(py::module_& m) {
  using namespace marionette::planning;

  py::class_<ImplicitSpec>(
      m, "ImplicitSpec",
      "One implicit constraint: kind relative (joint1, M1, joint2, M2, mask) | placement | "
      "complement (placement index) | locked (idx_q, idx_v, nq) | com (joint1, M1, mask x y z); "
      "level (0 = highest)")
      .def(py::init([](const std::string& kind, int level, int joint1, const Eigen::Matrix4d& M1,
                       int joint2, const Eigen::Matrix4d& M2, const std::vector<bool>& mask,
                       int placement, int idx_q, int idx_v, int nq) {
             ImplicitSpec s;
             s.kind = ImplicitKind(kind);
             s.level = level;
             s.joint1 = joint1;
             s.M1 = Pose(M1);
             s.joint2 = joint2;
             s.M2 = Pose(M2);
             if (mask.size() != 6)
               throw std::invalid_argument("a mask has 6 entries (x y z rx ry rz)");
             for (int i = 0; i < 6; ++i) s.mask[i] = mask[i];
             s.placement = placement;
             s.idx_q = idx_q;
             s.idx_v = idx_v;
             s.nq = nq;
             return s;
           }),
           py::arg("kind"), py::arg("level") = 0, py::arg("joint1") = 0,
           py::arg("M1") = Eigen::Matrix4d::Identity().eval(), py::arg("joint2") = 0,
           py::arg("M2") = Eigen::Matrix4d::Identity().eval(),
           py::arg("mask") = std::vector<bool>(6, true), py::arg("placement") = -1,
           py::arg("idx_q") = 0, py::arg("idx_v") = 0, py::arg("nq") = 0);

  py::class_<PlacementSpec>(
      m, "PlacementSpec",
      "Object surface on environment surface: per pair joint_e, M_env, joint_o, M_obj (4x4, "
      "z into the object), polygon (k x 2); margin; select (pair chosen per projection)")
      .def(py::init([](std::vector<int> joint_e, const std::vector<Eigen::Matrix4d>& M_env,
                       std::vector<int> joint_o, const std::vector<Eigen::Matrix4d>& M_obj,
                       std::vector<Eigen::MatrixX2d> polygons, double margin, bool select) {
             return PlacementSpec{std::move(joint_e),
                                  std::move(joint_o),
                                  Poses(M_env),
                                  Poses(M_obj),
                                  std::move(polygons),
                                  margin,
                                  select};
           }),
           py::arg("joint_e"), py::arg("M_env"), py::arg("joint_o"), py::arg("M_obj"),
           py::arg("polygons"), py::arg("margin"), py::arg("select"));

  py::class_<Projector>(
      m, "Projector",
      "Newton-Raphson projection onto implicit constraints with explicit substitution "
      "(twin of marionette.planning.projector.Projector.project)")
      .def(py::init([](const std::vector<JointSpec>& joints, std::vector<ImplicitSpec> implicit,
                       std::vector<PlacementSpec> placements, std::vector<int> locked_idx_q,
                       std::vector<int> locked_nq, std::vector<int> relative_idx_q,
                       std::vector<int> relative_parent, std::vector<int> relative_output,
                       const std::vector<Eigen::Matrix4d>& relative_M_PO, bool patchable,
                       std::vector<int> static_joints, std::vector<int> free_idx,
                       std::vector<int> bounded_idx_q, Eigen::VectorXd lower, Eigen::VectorXd upper,
                       std::vector<int> sat_k, std::vector<int> sat_q, Eigen::VectorXd sat_lo,
                       Eigen::VectorXd sat_hi, const std::string& line_search, double alpha0,
                       double alpha_max, double K, double alpha_min, double max_step,
                       double damping) {
             ProjectorSpec s;
             s.implicit = std::move(implicit);
             s.placements = std::move(placements);
             s.locked_idx_q = std::move(locked_idx_q);
             s.locked_nq = std::move(locked_nq);
             s.relative_idx_q = std::move(relative_idx_q);
             s.relative_parent = std::move(relative_parent);
             s.relative_output = std::move(relative_output);
             s.relative_M_PO = Poses(relative_M_PO);
             s.patchable = patchable;
             s.static_joints = std::move(static_joints);
             s.free_idx = std::move(free_idx);
             s.bounded_idx_q = std::move(bounded_idx_q);
             s.lower = std::move(lower);
             s.upper = std::move(upper);
             s.sat_k = std::move(sat_k);
             s.sat_q = std::move(sat_q);
             s.sat_lo = std::move(sat_lo);
             s.sat_hi = std::move(sat_hi);
             s.line_search = {
                 LineSearchKind(line_search), alpha0, alpha_max, K, alpha_min, max_step};
             s.damping = damping;
             return std::make_unique<Projector>(BuildKinematicModel(joints), std::move(s));
           }),
           py::arg("joints"), py::arg("implicit"), py::arg("placements"), py::arg("locked_idx_q"),
           py::arg("locked_nq"), py::arg("relative_idx_q"), py::arg("relative_parent"),
           py::arg("relative_output"), py::arg("relative_M_PO"), py::arg("patchable"),
           py::arg("static_joints"), py::arg("free_idx"), py::arg("bounded_idx_q"),
           py::arg("lower"), py::arg("upper"), py::arg("sat_k"), py::arg("sat_q"),
           py::arg("sat_lo"), py::arg("sat_hi"), py::arg("line_search"), py::arg("alpha0"),
           py::arg("alpha_max"), py::arg("K"), py::arg("alpha_min"), py::arg("max_step"),
           py::arg("damping"))
      .def(
          "project",
          [](Projector& p, Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
             std::vector<int> pairs, double error_threshold, int max_iterations) {
            const ProjectionOutcome r = p.Project(q, rhs, &pairs, error_threshold, max_iterations);
            return py::make_tuple(static_cast<int>(r.status), r.iterations, r.error_norm, pairs);
          },
          py::arg("q").noconvert(), py::arg("rhs"), py::arg("pairs"), py::arg("error_threshold"),
          py::arg("max_iterations"),
          "Project q (float64 contiguous nq array, modified in place): (status code, iterations, "
          "|e|, surface "
          "pairs); status 0 success, 1 iteration limit, 2 not decreasing, 3 local minimum, 4 not "
          "finite")
      .def(
          "is_satisfied",
          [](Projector& p, const Eigen::VectorXd& q, const Eigen::VectorXd& rhs,
             std::vector<int> pairs, double threshold) {
            const bool ok = p.IsSatisfied(q, rhs, &pairs, threshold);
            return py::make_tuple(ok, pairs);
          },
          py::arg("q"), py::arg("rhs"), py::arg("pairs"), py::arg("threshold"),
          "(does q satisfy every constraint within threshold, surface pairs)")
      .def(
          "error",
          [](Projector& p, Eigen::VectorXd q, const Eigen::VectorXd& rhs, std::vector<int> pairs) {
            return p.Error(q, rhs, &pairs);
          },
          py::arg("q"), py::arg("rhs"), py::arg("pairs"),
          "Stacked implicit errors at q (no substitution)")
      .def(
          "jacobian",
          [](Projector& p, Eigen::VectorXd q, const Eigen::VectorXd& rhs, std::vector<int> pairs) {
            return p.Jacobian(q, rhs, &pairs);
          },
          py::arg("q"), py::arg("rhs"), py::arg("pairs"),
          "Stacked implicit Jacobians (size x nv) at q, before the chain rule (no substitution)")
      .def_property_readonly("rhs_size", &Projector::rhs_size)
      .def_property_readonly("size", &Projector::size)
      .def_property_readonly("num_placements", &Projector::num_placements)
      .def_property_readonly("nq", [](const Projector& p) { return p.model().nq; });

  m.def(
      "plan_in_constrained_leaf",
      [](PathValidator& validator, Projector& projector, const PairMotion& motion,
         const Eigen::VectorXd& q_start, const Eigen::VectorXd& q_goal, const Eigen::VectorXd& rhs,
         std::vector<int> pairs, std::vector<int> sample_idx_q, const Eigen::VectorXd& lower,
         const Eigen::VectorXd& upper, const Substitution& sub, double step, double error_threshold,
         int projection_iterations, int max_iterations, double max_time_s, std::uint32_t seed) {
        ConstrainedLeafQuery query{
            q_start, q_goal, rhs,  std::move(pairs), std::move(sample_idx_q), lower,
            upper,   sub,    step, error_threshold,  projection_iterations};
        const LeafPlannerOptions options{max_iterations, max_time_s, 0.0, seed};
        LeafPlanResult r;
        {
          py::gil_scoped_release release;
          r = PlanInConstrainedLeaf(&validator, &projector, motion, query, options);
        }
        return py::make_tuple(r.solved, r.waypoints, r.iterations, r.queries);
      },
      py::arg("validator"), py::arg("projector"), py::arg("motion"), py::arg("q_start"),
      py::arg("q_goal"), py::arg("rhs"), py::arg("pairs"), py::arg("sample_idx_q"),
      py::arg("lower"), py::arg("upper"), py::arg("substitution"), py::arg("step"),
      py::arg("error_threshold"), py::arg("projection_iterations"), py::arg("max_iterations"),
      py::arg("max_time_s"), py::arg("seed"),
      "RRT-Connect on a leaf with implicit constraints "
      "(cpp/include/marionette/planning/leaf_planner.h): (solved, waypoints (k x nq), "
      "iterations, pair queries)");
}

}  // namespace marionette::bindings
