// marionette._core.solve_hierarchy: the strict-hierarchy algorithm of cpp/src/sot/hierarchy.cc,
// for checks against independent solvers from Python (tests/python/sot). Bindings only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

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

}  // namespace

void RegisterSot(py::module_& m) {
  m.def(
      "solve_hierarchy",
      [](const std::vector<std::vector<py::dict>>& levels, double damping,
         double qp_regularization) {
        if (levels.empty() || levels[0].empty()) throw py::value_error("no level");
        std::vector<sot::TaskTerms> terms;
        std::vector<std::vector<sot::TaskShape>> shapes;
        for (const auto& level : levels) {
          shapes.emplace_back();
          for (const py::dict& task : level) {
            terms.push_back(TermsFromDict(task));
            const sot::TaskTerms& t = terms.back();
            shapes.back().push_back(
                {static_cast<int>(t.lower.size()), t.inequality, t.unit_columns});
          }
        }
        sot::HierarchyOptions options;
        options.damping = damping;
        options.qp_regularization = qp_regularization;
        sot::Hierarchy h(static_cast<int>(terms[0].jacobian.cols()), shapes, options);
        sot::HierarchyWorkspace w(h);
        std::vector<const sot::TaskTerms*> pointers;
        for (const auto& t : terms) pointers.push_back(&t);
        Eigen::VectorXd v;
        sot::SolveHierarchy(h, pointers, &w, &v);
        const sot::HierarchyReport& r = w.report();
        py::dict report;
        report["ranks"] = r.ranks;
        report["num_qp"] = r.num_qp;
        report["num_active_set"] = r.num_active_set;
        report["gram_levels"] = r.gram_levels;
        report["qp_failures"] = r.qp_failures;
        return py::make_tuple(v, report);
      },
      py::arg("levels"), py::arg("damping") = 0.0, py::arg("qp_regularization") = 1e-10,
      "Solve a strict hierarchy: levels is a list (highest priority first) of lists of tasks, each "
      "a "
      "dict with jacobian, lower, upper (equality when absent), inequality, unit_columns. Returns "
      "(v, report). Defaults are the exact cascade (no damping, tiny QP regularisation).");
}

}  // namespace marionette::bindings
