#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "py_conversions.hpp"
#include "dcslam/core/config.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

void define_config(py::module_& m) {
  // The compiled twin of the Python dataclass dcslam.SlamConfig; the dataclass builds it
  // (SlamConfig._to_core) so option names and checks live in one place: SlamConfig::validate.
  py::class_<SlamConfig>(m, "SlamConfig")
      .def(py::init<>())
      .def_property(
          "observation", [](const SlamConfig& c) { return std::string(to_string(c.observation)); },
          [](SlamConfig& c, const std::string& v) {
            c.observation = parse_observation_model(v, "SlamConfig.observation");
          })
      .def_property(
          "sensor_offset", [](const SlamConfig& c) { return c.sensor_offset; },
          [](SlamConfig& c, const py::object& v) {
            c.sensor_offset = as_vector(v, 3, "SlamConfig.sensor_offset");
          })
      .def_property(
          "association", [](const SlamConfig& c) { return std::string(to_string(c.association)); },
          [](SlamConfig& c, const std::string& v) {
            c.association = parse_association(v, "SlamConfig.association");
          })
      .def_readwrite("gate_confidence", &SlamConfig::gate_confidence)
      .def_readwrite("unexplained_density", &SlamConfig::unexplained_density)
      .def_readwrite("new_feature_margin", &SlamConfig::new_feature_margin)
      .def_readwrite("new_feature_beside_tentative", &SlamConfig::new_feature_beside_tentative)
      .def_readwrite("confirmed_first_confidence", &SlamConfig::confirmed_first_confidence)
      .def_readwrite("jcbb_max_nodes", &SlamConfig::jcbb_max_nodes)
      .def_readwrite("min_sightings", &SlamConfig::min_sightings)
      .def_readwrite("tentative_window", &SlamConfig::tentative_window)
      .def_readwrite("merge_radius", &SlamConfig::merge_radius)
      .def_readwrite("final_merge_confidence", &SlamConfig::final_merge_confidence)
      .def_readwrite("final_merge_shared_scans", &SlamConfig::final_merge_shared_scans)
      .def_readwrite("join_merge_max_leaves", &SlamConfig::join_merge_max_leaves)
      .def_readwrite("weak_join_pairings", &SlamConfig::weak_join_pairings)
      .def_readwrite("local_map_features", &SlamConfig::local_map_features)
      .def_property(
          "join_association",
          [](const SlamConfig& c) { return std::string(to_string(c.join_association)); },
          [](SlamConfig& c, const std::string& v) {
            c.join_association = parse_join_association(v, "SlamConfig.join_association");
          })
      .def_readwrite("rjc_b", &SlamConfig::rjc_b)
      .def_readwrite("rjc_p_good", &SlamConfig::rjc_p_good)
      .def_readwrite("rjc_p_fail", &SlamConfig::rjc_p_fail)
      .def_readwrite("rjc_exchange_crossed", &SlamConfig::rjc_exchange_crossed)
      .def_readwrite("join_iterations", &SlamConfig::join_iterations)
      .def_readwrite("join_feature_sigma", &SlamConfig::join_feature_sigma)
      .def_readwrite("large_overlap_confidence", &SlamConfig::large_overlap_confidence)
      .def_readwrite("chunked_jcbb_min_overlap", &SlamConfig::chunked_jcbb_min_overlap)
      .def_readwrite("join_rival_margin", &SlamConfig::join_rival_margin)
      .def_readwrite("tree_relinearisation", &SlamConfig::tree_relinearisation)
      .def_readwrite("tree_relinearisation_tolerance", &SlamConfig::tree_relinearisation_tolerance)
      .def_readwrite("seed", &SlamConfig::seed)
      .def_readwrite("amortize", &SlamConfig::amortize)
      .def_readwrite("threaded_joins", &SlamConfig::threaded_joins)
      .def_readwrite("estimate_threads", &SlamConfig::estimate_threads)
      .def_readwrite("keep_local_map_poses", &SlamConfig::keep_local_map_poses)
      .def_readwrite("online_localisation_sigma", &SlamConfig::online_localisation_sigma)
      .def("validate", &SlamConfig::validate);
}

}  // namespace dcslam::bindings
