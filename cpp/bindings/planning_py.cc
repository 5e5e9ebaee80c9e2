// marionette._core.planning: the certified path validator of cpp/src/planning, used by
// marionette.planning.collision (which builds the specs from its Pinocchio/coal models).
// Bindings only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <stdexcept>

#include "marionette/planning/leaf_planner.h"
#include "marionette/planning/path_validator.h"

namespace py = pybind11;

namespace marionette::bindings {

void RegisterPlanningProjector(py::module_& m);  // planning_projector_py.cc

namespace {

pinocchio::SE3 SE3From(const Eigen::Matrix4d& M) {
  return pinocchio::SE3(Eigen::Matrix3d(M.topLeftCorner<3, 3>()),
                        Eigen::Vector3d(M.topRightCorner<3, 1>()));
}

using BoolArray = Eigen::Array<bool, Eigen::Dynamic, 1>;

}  // namespace

void RegisterPlanning(py::module_& parent) {
  using namespace marionette::planning;
  py::module_ m =
      parent.def_submodule("planning", "Certified continuous collision checking of paths");
  // std::invalid_argument -> ValueError (pybind11's default translation).

  py::class_<JointSpec>(m, "JointSpec",
                        "One joint: name, parent, kind (RX ... FreeFlyer), axis, placement (4x4), "
                        "body mass, lever (CoM in the joint frame), rotational inertia (3x3)")
      .def(py::init([](std::string name, int parent, std::string kind, Eigen::Vector3d axis,
                       Eigen::Matrix4d placement, double mass, Eigen::Vector3d lever,
                       Eigen::Matrix3d rotational_inertia) {
             return JointSpec{std::move(name),    parent, std::move(kind), axis,
                              SE3From(placement), mass,   lever,           rotational_inertia};
           }),
           py::arg("name"), py::arg("parent"), py::arg("kind"), py::arg("axis"),
           py::arg("placement"), py::arg("mass") = 0.0,
           py::arg("lever") = Eigen::Vector3d::Zero().eval(),
           py::arg("rotational_inertia") = Eigen::Matrix3d::Zero().eval());

  py::class_<GeometrySpec>(
      m, "GeometrySpec",
      "One collision geometry: kind convex (points, triangles) | box (half_side) | "
      "sphere (radius) | cylinder, capsule (radius, half_length)")
      .def(py::init([](std::string name, int parent_joint, Eigen::Matrix4d placement,
                       std::string kind, Eigen::MatrixX3d points, Eigen::MatrixX3i triangles,
                       Eigen::Vector3d half_side, double radius, double half_length) {
             GeometrySpec g;
             g.name = std::move(name);
             g.parent_joint = parent_joint;
             g.placement = SE3From(placement);
             g.kind = std::move(kind);
             g.points = std::move(points);
             g.triangles = std::move(triangles);
             g.half_side = half_side;
             g.radius = radius;
             g.half_length = half_length;
             return g;
           }),
           py::arg("name"), py::arg("parent_joint"), py::arg("placement"), py::arg("kind"),
           py::arg("points") = Eigen::MatrixX3d(), py::arg("triangles") = Eigen::MatrixX3i(),
           py::arg("half_side") = Eigen::Vector3d::Zero(), py::arg("radius") = 0.0,
           py::arg("half_length") = 0.0);

  py::class_<Substitution>(
      m, "Substitution",
      "Explicit constraints of a path: locked joint values, attached free-flyers")
      .def(py::init([](std::vector<int> locked_idx_q, std::vector<Eigen::VectorXd> locked_value,
                       std::vector<int> attached_idx_q, std::vector<int> attached_parent,
                       const std::vector<Eigen::Matrix4d>& attached_M_PO) {
             Substitution s{std::move(locked_idx_q),
                            std::move(locked_value),
                            std::move(attached_idx_q),
                            std::move(attached_parent),
                            {}};
             for (const auto& M : attached_M_PO) s.attached_M_PO.push_back(SE3From(M));
             return s;
           }),
           py::arg("locked_idx_q"), py::arg("locked_value"), py::arg("attached_idx_q"),
           py::arg("attached_parent"), py::arg("attached_M_PO"));

  py::class_<PairMotion>(m, "PairMotion",
                         "Per pair: rigid, skip (npairs), R, L (npairs x njoints), clearance "
                         "(npairs [m], or empty: the contact distance)")
      .def(py::init([](BoolArray rigid, BoolArray skip, Eigen::MatrixXd R, Eigen::MatrixXd L,
                       Eigen::VectorXd clearance) {
             return PairMotion{std::move(rigid), std::move(skip), std::move(R), std::move(L),
                               std::move(clearance)};
           }),
           py::arg("rigid"), py::arg("skip"), py::arg("R"), py::arg("L"),
           py::arg("clearance") = Eigen::VectorXd())
      .def_readonly("rigid", &PairMotion::rigid)
      .def_readonly("skip", &PairMotion::skip)
      .def_readonly("R", &PairMotion::R)
      .def_readonly("L", &PairMotion::L)
      .def_readonly("clearance", &PairMotion::clearance);

  py::class_<PathValidator>(m, "PathValidator",
                            "Certified continuous collision checking of constrained polylines")
      .def(py::init(
               [](const std::vector<JointSpec>& joints, const std::vector<GeometrySpec>& geometries,
                  const std::vector<std::pair<int, int>>& pairs, double contact, int max_queries) {
                 pinocchio::Model model = BuildKinematicModel(joints);
                 pinocchio::GeometryModel gm = BuildGeometryModel(model, geometries, pairs);
                 return std::make_unique<PathValidator>(std::move(model), std::move(gm), contact,
                                                        max_queries);
               }),
           py::arg("joints"), py::arg("geometries"), py::arg("pairs"), py::arg("contact"),
           py::arg("max_queries"))
      .def(
          "validate",
          [](PathValidator& v, const Eigen::MatrixXd& points, const Eigen::VectorXd& cum,
             const Substitution& sub, const PairMotion& motion, bool probes) {
            const ValidationResult r = v.Validate(Polyline{points, cum}, sub, motion, probes);
            return py::make_tuple(r.valid, r.s_valid, r.queries, r.grazing);
          },
          py::arg("points"), py::arg("cum"), py::arg("substitution"), py::arg("motion"),
          py::arg("probes"),
          "(valid, s_valid, pair queries, refused as grazing) of the path points (k x nq) at arc "
          "lengths cum (k)")
      .def(
          "is_clear",
          [](PathValidator& v, const Eigen::VectorXd& q, const PairMotion& motion) {
            return v.IsClear(q, motion);
          },
          py::arg("q"), py::arg("motion"),
          "True when every pair but the skipped ones is farther than its clearance at q")
      .def(
          "eval",
          [](PathValidator& v, const Eigen::MatrixXd& points, const Eigen::VectorXd& cum,
             const Substitution& sub, double s) {
            if (points.rows() < 2 || points.cols() != v.model().nq || cum.size() != points.rows())
              throw std::invalid_argument("points must be (k >= 2) x nq and cum (k)");
            Eigen::VectorXd q(v.model().nq);
            v.Eval(Polyline{points, cum}, sub, s, &q);
            return q;
          },
          py::arg("points"), py::arg("cum"), py::arg("substitution"), py::arg("s"))
      .def(
          "pair_speeds",
          [](PathValidator& v, const Eigen::VectorXd& qa, const Eigen::VectorXd& qb,
             const PairMotion& motion) {
            if (qa.size() != v.model().nq || qb.size() != v.model().nq)
              throw std::invalid_argument("qa and qb must have nq entries");
            if (motion.rigid.size() != v.num_pairs() || motion.skip.size() != v.num_pairs() ||
                motion.R.rows() != v.num_pairs() || motion.L.rows() != v.num_pairs() ||
                motion.R.cols() != v.model().njoints || motion.L.cols() != v.model().njoints)
              throw std::invalid_argument("pair motion sizes do not match the model");
            Eigen::VectorXd u(v.num_pairs());
            v.PairSpeeds(qa, qb, motion, &u);
            return u;
          },
          py::arg("qa"), py::arg("qb"), py::arg("motion"),
          "Bound on how fast each pair closes its distance along qa -> qb (npairs) [m per unit t]")
      .def(
          "plan_in_leaf",
          [](PathValidator& v, const PairMotion& motion, const Eigen::VectorXd& q_start,
             const Eigen::VectorXd& q_goal, std::vector<int> free_idx_q,
             const Eigen::VectorXd& lower, const Eigen::VectorXd& upper, const Substitution& sub,
             int max_iterations, double max_time_s, double range, std::uint32_t seed) {
            const LeafQuery query{q_start, q_goal, std::move(free_idx_q), lower, upper, sub};
            const LeafPlannerOptions options{max_iterations, max_time_s, range, seed};
            LeafPlanResult r;
            {
              py::gil_scoped_release release;
              r = PlanInLeaf(&v, motion, query, options);
            }
            return py::make_tuple(r.solved, r.waypoints, r.iterations, r.queries);
          },
          py::arg("motion"), py::arg("q_start"), py::arg("q_goal"), py::arg("free_idx_q"),
          py::arg("lower"), py::arg("upper"), py::arg("substitution"), py::arg("max_iterations"),
          py::arg("max_time_s"), py::arg("range"), py::arg("seed"),
          "RRT-Connect in one leaf (cpp/include/marionette/planning/leaf_planner.h): (solved, "
          "waypoints (k x nq), iterations, pair queries)")
      .def("is_valid", &PathValidator::IsValid, py::arg("q"), py::arg("skip"))
      .def("distances", &PathValidator::Distances, py::arg("q"))
      .def_property_readonly("nq", [](const PathValidator& v) { return v.model().nq; })
      .def_property_readonly("num_pairs", &PathValidator::num_pairs)
      .def_property_readonly("idx_qs", [](const PathValidator& v) {
        return std::vector<int>(v.model().idx_qs.begin(), v.model().idx_qs.end());
      });
  RegisterPlanningProjector(m);
}

}  // namespace marionette::bindings
