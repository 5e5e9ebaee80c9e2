// marionette._core: the C++ side of marionette as a Python extension.
// Bindings only; the logic lives in the libraries under cpp/src. One Register<Layer> per layer.
#include <pybind11/pybind11.h>

namespace py = pybind11;

namespace marionette::bindings {
void RegisterGraph(py::module_& m);
void RegisterSim(py::module_& m);
void RegisterSot(py::module_& m);
void RegisterPlanning(py::module_& m);
}  // namespace marionette::bindings

PYBIND11_MODULE(_core, m) {
  m.doc() = "marionette C++ core (dynamic graph, solver, simulation) for Python";
  m.attr("__version__") = MARIONETTE_VERSION;
  marionette::bindings::RegisterGraph(m);
  marionette::bindings::RegisterSim(m);
  marionette::bindings::RegisterSot(m);
  marionette::bindings::RegisterPlanning(m);
}
