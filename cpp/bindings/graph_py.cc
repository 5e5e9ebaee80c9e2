// marionette._core.dg: the dynamic graph from Python (bindings only).
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "marionette/graph/tracer.h"

namespace py = pybind11;
namespace dg = marionette::graph;

namespace pybind11 {
// Signals are InputSignal<T> / OutputSignal<T>, which Python does not know: expose inputs as
// InputSignal and every other signal as Signal.
template <>
struct polymorphic_type_hook<dg::SignalBase> {
  static const void* get(const dg::SignalBase* src, const std::type_info*& type) {
    if (src != nullptr && src->is_input()) {
      type = &typeid(dg::InputSignalBase);
      return static_cast<const dg::InputSignalBase*>(src);
    }
    type = src != nullptr ? &typeid(dg::SignalBase) : nullptr;
    return src;
  }
};
}  // namespace pybind11

namespace marionette::bindings {
namespace {

// The current value of any signal as a Python float (scalar types), a 1-D array (vectors) or a
// 2-D array (matrices, SE3 as 4 x 4).
py::object SignalValue(const dg::SignalBase& s) {
  const dg::Shape shape = s.shape();
  std::vector<double> flat(shape.size());
  s.Flatten(flat.data());
  const std::string type = s.type_name();
  if (type == "double") return py::float_(flat[0]);
  if (type == "int") return py::int_(static_cast<int64_t>(flat[0]));
  if (type == "bool") return py::bool_(flat[0] != 0.0);
  if (type == "vector") return py::array_t<double>(shape.rows, flat.data());
  py::array_t<double, py::array::f_style> a({shape.rows, shape.cols});
  std::copy(flat.begin(), flat.end(), a.mutable_data());
  return std::move(a);
}

void SetInputValue(dg::InputSignalBase& in, const py::object& value) {
  auto a = py::array_t<double, py::array::f_style | py::array::forcecast>::ensure(value);
  if (!a) throw dg::GraphError("input " + in.full_name() + ": value is not numeric");
  in.SetFlat(a.data(), static_cast<int>(a.size()));
}

std::vector<const dg::SignalBase*> ToSignals(const std::vector<dg::SignalBase*>& v) {
  return {v.begin(), v.end()};
}

}  // namespace

void RegisterGraph(py::module_& parent) {
  py::module_ m = parent.def_submodule("dg", "Dynamic graph: entities, signals, builder, edits");
  py::register_exception<dg::GraphError>(m, "GraphError", PyExc_ValueError);

  py::class_<dg::Tick>(m, "Tick")
      .def(py::init([](int64_t index, double time, double dt) {
             return dg::Tick{index, time, dt};
           }),
           py::arg("index") = 0, py::arg("time") = 0.0, py::arg("dt") = 1e-3)
      .def_readwrite("index", &dg::Tick::index)
      .def_readwrite("time", &dg::Tick::time)
      .def_readwrite("dt", &dg::Tick::dt)
      .def("advance",
           [](dg::Tick& t) {
             ++t;
             return t;
           })
      .def("__repr__", [](const dg::Tick& t) {
        return "Tick(index=" + std::to_string(t.index) + ", time=" + std::to_string(t.time) + ")";
      });

  py::class_<dg::SignalBase>(m, "Signal")
      .def_property_readonly("name", &dg::SignalBase::name)
      .def_property_readonly("full_name", &dg::SignalBase::full_name)
      .def_property_readonly("kind", [](const dg::SignalBase& s) { return dg::ToString(s.kind()); })
      .def_property_readonly("type_name", &dg::SignalBase::type_name)
      .def_property_readonly(
          "shape",
          [](const dg::SignalBase& s) { return py::make_tuple(s.shape().rows, s.shape().cols); })
      .def_property_readonly("value", &SignalValue, "current value (no evaluation)")
      .def("pull", &dg::SignalBase::Pull, py::arg("tick"), "evaluate at tick (cached per tick)")
      .def_property_readonly("entity", [](const dg::SignalBase& s) { return s.owner().name(); })
      .def("__repr__", [](const dg::SignalBase& s) {
        return "<" + std::string(dg::ToString(s.kind())) + " " + s.full_name() + ">";
      });

  py::class_<dg::InputSignalBase, dg::SignalBase>(m, "InputSignal")
      .def_property_readonly("source",
                             [](const dg::InputSignalBase& in) -> py::object {
                               if (in.source() == nullptr) return py::none();
                               return py::str(in.source()->full_name());
                             })
      .def_property_readonly("is_plugged", &dg::InputSignalBase::is_plugged)
      .def_property_readonly("is_set", &dg::InputSignalBase::is_set)
      .def_property_readonly("settable", &dg::InputSignalBase::settable)
      .def("set_value", &SetInputValue, py::arg("value"), "hold a fixed value (numpy or float)");

  py::class_<dg::Entity, std::shared_ptr<dg::Entity>>(m, "Entity")
      .def_property_readonly("name", &dg::Entity::name)
      .def_property_readonly("type_name", &dg::Entity::type_name)
      .def("signal", &dg::Entity::signal, py::return_value_policy::reference_internal)
      .def(
          "input",
          [](const dg::Entity& e, std::string_view name) -> dg::InputSignalBase& {
            dg::SignalBase& s = e.signal(name);
            if (!s.is_input()) throw dg::GraphError(s.full_name() + " is not an input");
            return static_cast<dg::InputSignalBase&>(s);
          },
          py::return_value_policy::reference_internal)
      .def(
          "output",
          [](const dg::Entity& e, std::string_view name) -> dg::SignalBase& {
            dg::SignalBase& s = e.signal(name);
            if (s.is_input()) throw dg::GraphError(s.full_name() + " is not an output");
            return s;
          },
          py::return_value_policy::reference_internal)
      .def_property_readonly("inputs", &dg::Entity::inputs,
                             py::return_value_policy::reference_internal)
      .def_property_readonly("outputs", &dg::Entity::outputs,
                             py::return_value_policy::reference_internal)
      .def("__repr__", [](const dg::Entity& e) {
        return "<" + std::string(e.type_name()) + " '" + e.name() + "'>";
      });

  py::class_<dg::VectorConstant, dg::Entity, std::shared_ptr<dg::VectorConstant>>(m,
                                                                                  "VectorConstant")
      .def(py::init<std::string, const Eigen::VectorXd&>(), py::arg("name"), py::arg("value"));
  py::class_<dg::VectorSum, dg::Entity, std::shared_ptr<dg::VectorSum>>(m, "VectorSum")
      .def(py::init<std::string, int, int>(), py::arg("name"), py::arg("n"), py::arg("num_inputs"));
  py::class_<dg::VectorGain, dg::Entity, std::shared_ptr<dg::VectorGain>>(m, "VectorGain")
      .def(py::init<std::string, int, double>(), py::arg("name"), py::arg("n"), py::arg("gain"));
  py::class_<dg::MatrixVectorProduct, dg::Entity, std::shared_ptr<dg::MatrixVectorProduct>>(
      m, "MatrixVectorProduct")
      .def(py::init<std::string, int, int>(), py::arg("name"), py::arg("rows"), py::arg("cols"));
  py::class_<dg::VectorIntegrator, dg::Entity, std::shared_ptr<dg::VectorIntegrator>>(
      m, "VectorIntegrator")
      .def(py::init<std::string, const Eigen::VectorXd&>(), py::arg("name"), py::arg("initial"));
  py::class_<dg::Tracer, dg::Entity, std::shared_ptr<dg::Tracer>>(m, "Tracer")
      .def(
          py::init([](std::string name, int capacity, const std::vector<dg::SignalBase*>& signals) {
            return std::make_shared<dg::Tracer>(std::move(name), capacity, ToSignals(signals));
          }),
          py::arg("name"), py::arg("capacity"), py::arg("signals"))
      .def_property_readonly("column_names", &dg::Tracer::column_names)
      .def_property_readonly("size", &dg::Tracer::size)
      .def(
          "rows",
          [](const dg::Tracer& t) {
            py::array_t<double> a({t.size(), t.num_columns()});
            for (int i = 0; i < t.size(); ++i) {
              const std::vector<double> row = t.Row(i);
              std::copy(row.begin(), row.end(), a.mutable_data(i, 0));
            }
            return a;
          },
          "recorded rows, oldest first: tick, time, values...")
      .def("write_csv", &dg::Tracer::WriteCsv, py::arg("path"));

  py::class_<dg::Graph>(m, "Graph")
      .def("evaluate", &dg::Graph::Evaluate, py::arg("tick"))
      .def(
          "run", [](dg::Graph& g, dg::Tick& t, int64_t n) { dg::RunTicks(g, &t, n); },
          py::arg("tick"), py::arg("n"), "evaluate n ticks from tick (advanced in place)",
          py::call_guard<py::gil_scoped_release>())
      .def_property_readonly("entities", &dg::Graph::entities)
      .def(
          "entity",
          [](const dg::Graph& g, std::string_view name) {
            for (const auto& e : g.entities()) {
              if (e->name() == name) return e;
            }
            g.entity(name);  // throws with the list of entities
            return std::shared_ptr<dg::Entity>();
          },
          py::arg("name"))
      .def("signal", &dg::Graph::signal, py::return_value_policy::reference_internal)
      .def_property_readonly("num_signals", &dg::Graph::num_signals)
      .def_property_readonly("version", &dg::Graph::version)
      .def("to_dot", &dg::Graph::ToDot)
      .def("apply", &dg::Graph::Apply, py::arg("edit"),
           "apply a prepared edit between two ticks; False when the graph changed since");

  py::class_<dg::GraphBuilder>(m, "GraphBuilder")
      .def(py::init<>())
      .def(
          "add",
          [](dg::GraphBuilder& b, std::shared_ptr<dg::Entity> e) {
            b.AddShared(e);
            return e;
          },
          py::arg("entity"))
      .def("connect",
           py::overload_cast<dg::SignalBase&, dg::SignalBase&>(&dg::GraphBuilder::Connect),
           py::arg("source"), py::arg("destination"))
      .def("connect",
           py::overload_cast<std::string_view, std::string_view>(&dg::GraphBuilder::Connect),
           py::arg("source"), py::arg("destination"))
      .def("build", &dg::GraphBuilder::Build);

  py::class_<dg::GraphEdit>(m, "GraphEdit")
      .def(py::init<const dg::Graph&>(), py::arg("graph"))
      .def(
          "add",
          [](dg::GraphEdit& ed, std::shared_ptr<dg::Entity> e) {
            ed.AddShared(e);
            return e;
          },
          py::arg("entity"))
      .def("remove", &dg::GraphEdit::Remove, py::arg("name"))
      .def("connect", py::overload_cast<dg::SignalBase&, dg::SignalBase&>(&dg::GraphEdit::Connect),
           py::arg("source"), py::arg("destination"))
      .def("connect",
           py::overload_cast<std::string_view, std::string_view>(&dg::GraphEdit::Connect),
           py::arg("source"), py::arg("destination"))
      .def("prepare", &dg::GraphEdit::Prepare)
      .def_property_readonly("prepared", &dg::GraphEdit::prepared);
}

}  // namespace marionette::bindings
