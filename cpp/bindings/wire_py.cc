// marionette._wire: the LCM boundary's C++ parts that Python processes use.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cstring>
#include <stdexcept>

#include "marionette/lcm/heartbeat.h"
#include "marionette/lcmt_camera_image.hpp"

namespace py = pybind11;
using marionette::wire::Heartbeat;
using marionette::wire::HeartbeatOptions;

namespace {

template <typename T>
py::array_t<T> Array(const std::vector<T>& values) {
  py::array_t<T> out(static_cast<py::ssize_t>(values.size()));
  if (!values.empty()) std::memcpy(out.mutable_data(), values.data(), values.size() * sizeof(T));
  return out;
}

// lcm-gen's C++ decoder, the arrays handed over as numpy arrays. lcm-gen's Python decoder makes
// the 307 200 depth pixels of a 640 x 480 frame a tuple of Python ints, then numpy an array of
// them: a quarter of `marionette perceive`'s time in a deburr trial.
py::dict DecodeCameraImage(const py::bytes& data) {
  char* bytes = nullptr;
  Py_ssize_t size = 0;
  if (PyBytes_AsStringAndSize(data.ptr(), &bytes, &size) != 0) throw py::error_already_set();
  marionette::lcmt_camera_image msg;
  int decoded = -1;
  {
    py::gil_scoped_release release;  // the bytes object is kept alive by the caller
    decoded = msg.decode(bytes, 0, static_cast<int>(size));
  }
  if (decoded < 0) {
    throw std::invalid_argument("not an lcmt_camera_image (" + std::to_string(size) + " bytes)");
  }
  py::dict out;
  out["utime"] = msg.utime;
  out["camera_name"] = msg.camera_name;
  out["frame_name"] = msg.frame_name;
  out["width"] = msg.width;
  out["height"] = msg.height;
  out["fx"] = msg.fx;
  out["fy"] = msg.fy;
  out["cx"] = msg.cx;
  out["cy"] = msg.cy;
  out["depth_scale"] = msg.depth_scale;
  out["camera_position"] =
      py::make_tuple(msg.camera_position[0], msg.camera_position[1], msg.camera_position[2]);
  out["camera_quaternion"] = py::make_tuple(msg.camera_quaternion[0], msg.camera_quaternion[1],
                                            msg.camera_quaternion[2], msg.camera_quaternion[3]);
  out["num_rgb"] = msg.num_rgb;
  out["rgb"] = Array(msg.rgb);
  out["num_depth"] = msg.num_depth;
  out["depth"] = Array(msg.depth);
  return out;
}

}  // namespace

PYBIND11_MODULE(_wire, m) {
  m.doc() =
      "marionette's LCM boundary in C++: the supervisor's heartbeat thread, the camera frame's "
      "decoder";
  m.def("decode_camera_image", &DecodeCameraImage, py::arg("data"), R"doc(
An lcmt_camera_image's fields (a dict) decoded by lcm-gen's C++ decoder, rgb (uint8) and depth
(int16) as numpy arrays; ValueError when the bytes are not one.)doc");
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
