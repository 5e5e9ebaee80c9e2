// marionette._wire: the LCM boundary's C++ parts that Python processes use.
#include <pybind11/pybind11.h>

#include "marionette/lcm/heartbeat.h"

namespace py = pybind11;
using marionette::wire::Heartbeat;
using marionette::wire::HeartbeatOptions;

PYBIND11_MODULE(_wire, m) {
  m.doc() = "marionette's LCM boundary in C++: the supervisor's heartbeat thread";
  py::class_<Heartbeat>(m, "Heartbeat", R"doc(
The supervisor's heartbeat (COMMAND "heartbeat" every period_s on url, signed with key when it
is not empty) from a C++ thread that never takes the interpreter's lock: a Python thread
holding it for a while does not silence the supervisor. It beats while feed() was called within
the last hang_s: a hung owner falls silent hang_s later, a dead process at once. Each beat names
this process, so that a controller on the same machine holds the moment it exits.)doc")
      .def(py::init([](const std::string& url, std::string source, const py::bytes& key,
                       double period_s, double hang_s) {
             return std::make_unique<Heartbeat>(url, std::move(source), std::string(key),
                                                HeartbeatOptions{period_s, hang_s});
           }),
           py::arg("url"), py::arg("source"), py::arg("key") = py::bytes(),
           py::arg("period_s") = HeartbeatOptions{}.period_s,
           py::arg("hang_s") = HeartbeatOptions{}.hang_s)
      .def("feed", &Heartbeat::Feed, "The owner is alive.")
      .def("stop", &Heartbeat::Stop, py::call_guard<py::gil_scoped_release>(),
           "Stops beating and joins the thread (idempotent).")
      .def_property_readonly("beats", &Heartbeat::beats)
      .def_property_readonly("withheld", &Heartbeat::withheld,
                             "Beats not sent because feed() was not called within hang_s.")
      .def_property_readonly("longest_feed_gap_s", &Heartbeat::longest_feed_gap_s,
                             "The longest time between two feed() calls so far [s].")
      .def_property_readonly("longest_beat_gap_s", &Heartbeat::longest_beat_gap_s,
                             "The longest time between two beats sent so far [s].");
}
