// marionette._core.solve_hierarchy: the strict-hierarchy algorithm of cpp/src/sot/hierarchy.cc,
// for checks against independent solvers from Python (tests/python/sot). Bindings only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>

#include "marionette/sot/feature_gripper_admittance.h"
#include "marionette/sot/hierarchy.h"

namespace py = pybind11;

namespace marionette::bindings {

namespace {

// One task as a dict: jacobian (k x nv), lower (k), upper (k), inequality (bool), unit_columns.
sot::TaskTerms TermsFromDict(const py::dict& d) {
  sot::TaskTerms t;
  t.jacobian = d["jacobian"].cast<Eigen::MatrixXd>();
  t.lower = d["lower"].cast<Eigen::VectorXd>();
  t.upper = d.contains("upper") ? d["upper"].cast<Eigen::VectorXd>() : t.lower;
  t.inequality = d.contains("inequality") && d["inequality"].cast<bool>();
  if (d.contains("unit_columns")) t.unit_columns = d["unit_columns"].cast<std::vector<int>>();
  if (t.lower.size() != t.jacobian.rows() || t.upper.size() != t.jacobian.rows()) {
    throw py::value_error("a task's lower/upper must have one entry per Jacobian row");
  }
  return t;
}

// A Hierarchy built from the shapes of a list of levels, with its workspace kept across solves
// (as the Solver entity keeps it across ticks: the active-set shortcut's first guess is the
// last solve's active set).
class PyHierarchy {
 public:
  PyHierarchy(const std::vector<std::vector<py::dict>>& levels, double damping,
              double qp_regularization, bool active_set_shortcut) {
    if (levels.empty() || levels[0].empty()) throw py::value_error("no level");
    std::vector<std::vector<sot::TaskShape>> shapes;
    int nv = -1;
    for (const auto& level : levels) {
      shapes.emplace_back();
      for (const py::dict& task : level) {
        const sot::TaskTerms t = TermsFromDict(task);
        if (nv < 0) nv = static_cast<int>(t.jacobian.cols());
        shapes.back().push_back({static_cast<int>(t.lower.size()), t.inequality, t.unit_columns});
      }
    }
    sot::HierarchyOptions options;
    options.damping = damping;
    options.qp_regularization = qp_regularization;
    options.active_set_shortcut = active_set_shortcut;
    hierarchy_ = std::make_unique<sot::Hierarchy>(nv, std::move(shapes), options);
    workspace_ = std::make_unique<sot::HierarchyWorkspace>(*hierarchy_);
  }

  py::tuple Solve(const std::vector<std::vector<py::dict>>& levels) {
    std::vector<sot::TaskTerms> terms;
    for (const auto& level : levels) {
      for (const py::dict& task : level) terms.push_back(TermsFromDict(task));
    }
    std::vector<const sot::TaskTerms*> pointers;
    for (const auto& t : terms) pointers.push_back(&t);
    Eigen::VectorXd v;
    sot::SolveHierarchy(*hierarchy_, pointers, workspace_.get(), &v);
    const sot::HierarchyReport& r = workspace_->report();
    py::dict report;
    report["ranks"] = r.ranks;
    report["num_qp"] = r.num_qp;
    report["num_active_set"] = r.num_active_set;
    report["qp_levels"] = r.qp_levels;
    report["active_set_levels"] = r.active_set_levels;
    report["gram_levels"] = r.gram_levels;
    report["qp_failures"] = r.qp_failures;
    report["remaining_dof"] = r.remaining_dof;
    return py::make_tuple(v, report);
  }

 private:
  std::unique_ptr<sot::Hierarchy> hierarchy_;
  std::unique_ptr<sot::HierarchyWorkspace> workspace_;
};

#define MARIONETTE_LEVELS_DOC                                                                \
  "levels is a list (highest priority first) of lists of tasks, each a dict with jacobian, " \
  "lower, "                                                                                  \
  "upper (equality when absent), inequality, unit_columns"

}  // namespace

void RegisterSot(py::module_& m) {
  py::class_<PyHierarchy>(m, "Hierarchy",
                          "A strict hierarchy and its workspace, kept across solves (the shapes "
                          "are those of `levels`): " MARIONETTE_LEVELS_DOC
                          ". Defaults are the exact cascade.")
      .def(py::init<const std::vector<std::vector<py::dict>>&, double, double, bool>(),
           py::arg("levels"), py::arg("damping") = 0.0, py::arg("qp_regularization") = 0.0,
           py::arg("active_set_shortcut") = true)
      .def("solve", &PyHierarchy::Solve, py::arg("levels"),
           "Solve levels of the same shapes; returns (v, report).");
  m.def(
      "solve_hierarchy",
      [](const std::vector<std::vector<py::dict>>& levels, double damping, double qp_regularization,
         bool active_set_shortcut) {
        return PyHierarchy(levels, damping, qp_regularization, active_set_shortcut).Solve(levels);
      },
      py::arg("levels"), py::arg("damping") = 0.0, py::arg("qp_regularization") = 0.0,
      py::arg("active_set_shortcut") = true,
      "Solve a strict hierarchy once: " MARIONETTE_LEVELS_DOC
      ". Returns (v, report). Defaults are the exact cascade (no damping, no QP "
      "regularisation).");
  m.def(
      "gripper_admittance_defaults",
      [] {
        const sot::GripperAdmittanceOptions o;
        return py::dict(
            py::arg("force_target") = o.force_target,
            py::arg("force_threshold") = o.force_threshold,
            py::arg("release_force") = o.release_force,
            py::arg("admittance_gain") = o.admittance_gain, py::arg("lever_arm") = o.lever_arm,
            py::arg("torque_per_effort") = o.torque_per_effort,
            py::arg("cutoff_frequency") = o.cutoff_frequency, py::arg("speed") = o.speed,
            py::arg("acceleration") = o.acceleration,
            py::arg("closing_direction") = o.closing_direction, py::arg("task_gain") = o.task_gain,
            py::arg("release_after") = o.release_after, py::arg("release_rate") = o.release_rate);
      },
      "The gripper_admittance task's parameters when a spec does not give them (the "
      "controller's GripperAdmittanceOptions).");
}

}  // namespace marionette::bindings
