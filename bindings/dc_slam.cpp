#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "dcslam/dc_slam.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

py::dict join_event_dict(const JoinEvent& event) {
  py::dict out;
  out["index"] = event.index;
  out["leaves"] = event.leaves;
  out["step_created"] = event.step_created;
  out["step_finished"] = event.step_finished;
  out["features_first"] = event.report.features_first;
  out["features_second"] = event.report.features_second;
  out["features_joined"] = event.report.features_joined;
  out["overlap"] = event.report.overlap;
  out["pairings"] = event.report.pairings;
  out["tries"] = event.report.tries;
  out["iterations"] = event.report.iterations;
  out["seconds"] = event.report.seconds_total;
  out["seconds_association"] = event.report.seconds_association;
  out["work_units"] = event.report.work_units;
  return out;
}

}  // namespace

void define_dc_slam(py::module_& m) {
  py::class_<DCSlam, SlamFilter>(m, "DCSlam")
      .def(py::init<const SlamConfig&>(), py::arg("config"))
      .def("joins",
           [](const DCSlam& slam) {
             py::list out;
             for (const JoinEvent& event : slam.joins()) out.append(join_event_dict(event));
             return out;
           })
      .def("stack_shape", &DCSlam::stack_shape)
      .def("finish_joins", &DCSlam::finish_joins, py::call_guard<py::gil_scoped_release>())
      .def("local_map_size", [](const DCSlam& slam) { return slam.local_map().map().num_features(); });
}

}  // namespace dcslam::bindings
