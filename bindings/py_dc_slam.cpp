#include <pybind11/pybind11.h>
#include <pybind11/eigen.h>
#include <pybind11/stl.h>

#include <memory>
#include <optional>
#include <string>

#include "dcslam/joining/checkpoint.hpp"
#include "dcslam/joining/dc_slam.hpp"
#include "dcslam/core/errors.hpp"

namespace py = pybind11;

namespace dcslam::bindings {

namespace {

py::dict pairing_dict(const JoinPairingRecord& pairing) {
  py::dict record;
  record["first_ids"] = pairing.first_ids;
  record["second_ids"] = pairing.second_ids;
  record["pairs"] = pairing.pairs;
  record["truth_pairs"] = pairing.truth_pairs;
  record["truth_distance_sq"] = pairing.truth_distance_sq;
  record["truth_candidate"] = std::vector<bool>(pairing.truth_candidate.begin(), pairing.truth_candidate.end());
  record["truth_consistent"] = std::vector<bool>(pairing.truth_consistent.begin(), pairing.truth_consistent.end());
  record["own_pairs"] = pairing.own_pairs;
  record["merged"] = pairing.merged;
  record["disputed"] = pairing.disputed;
  return record;
}

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
  out["deferred_pairings"] = event.report.deferred_pairings;
  out["alternatives_taken"] = event.report.alternatives_taken;
  out["duplicates_merged"] = event.pairing.merged.size();
  out["tries"] = event.report.tries;
  out["chunked"] = event.report.chunked;
  out["widened"] = event.report.widened;
  out["iterations"] = event.report.iterations;
  out["seconds"] = event.report.seconds_total;
  out["seconds_association"] = event.report.seconds_association;
  out["work_units"] = event.report.work_units;
  return out;
}

py::list event_dicts(const std::vector<JoinEvent>& events) {
  py::list out;
  for (const JoinEvent& event : events) out.append(join_event_dict(event));
  return out;
}

py::list pairing_dicts(const std::vector<JoinEvent>& events) {
  py::list out;
  for (const JoinEvent& event : events) out.append(pairing_dict(event.pairing));
  return out;
}

}  // namespace

void define_dc_slam(py::module_& m) {
  py::class_<DCSlam, SlamFilter>(m, "DCSlam")
      .def(py::init<const SlamConfig&>(), py::arg("config"))
      .def(py::pickle(
          [](const DCSlam& filter) {
            std::string bytes;
            {
              py::gil_scoped_release release;
              bytes = save_checkpoint(filter);
            }
            return py::bytes(bytes);
          },
          [](const py::bytes& state) { return load_dc_checkpoint(std::string_view(state)); }))
      .def("joins", [](const DCSlam& slam) { return event_dicts(slam.joins()); })
      .def("set_join_oracle",
           [](DCSlam& slam, const std::vector<std::int64_t>& feature_ids,
              const std::vector<std::int64_t>& landmark_ids, const std::string& mode,
              Eigen::Index min_first_features, std::optional<Eigen::Index> max_first_features) {
             if (feature_ids.size() != landmark_ids.size()) {
               throw InvalidArgument("set_join_oracle: feature_ids and landmark_ids differ in length");
             }
             auto oracle = std::make_shared<JoinOracle>();
             if (mode == "truth") {
               oracle->mode = JoinOracle::Mode::Truth;
             } else if (mode == "among_candidates") {
               oracle->mode = JoinOracle::Mode::AmongCandidates;
             } else if (mode == "remove_wrong") {
               oracle->mode = JoinOracle::Mode::RemoveWrong;
             } else if (mode == "audit") {
               oracle->mode = JoinOracle::Mode::Audit;
             } else {
               throw InvalidArgument("set_join_oracle: mode must be 'truth', 'among_candidates', 'remove_wrong' or 'audit', got '" + mode + "'");
             }
             if (min_first_features < 0) {
               throw InvalidArgument("set_join_oracle: min_first_features must be >= 0, got " +
                                     std::to_string(min_first_features));
             }
             oracle->min_first_features = min_first_features;
             if (max_first_features) {
               if (*max_first_features < min_first_features) {
                 throw InvalidArgument("set_join_oracle: max_first_features must be >= min_first_features (" +
                                       std::to_string(min_first_features) + "), got " +
                                       std::to_string(*max_first_features));
               }
               oracle->max_first_features = *max_first_features;
             }
             for (std::size_t k = 0; k < feature_ids.size(); ++k) oracle->landmark_of[feature_ids[k]] = landmark_ids[k];
             slam.set_join_oracle(std::move(oracle));
           },
           py::arg("feature_ids"), py::arg("landmark_ids"), py::arg("mode"), py::arg("min_first_features") = 0,
           py::arg("max_first_features") = py::none())
      .def("join_pairings", [](const DCSlam& slam) { return pairing_dicts(slam.joins()); })
      .def("fold_joins", [](const DCSlam& slam) { return event_dicts(slam.fold_joins()); })
      .def("fold_pairings", [](const DCSlam& slam) { return pairing_dicts(slam.fold_joins()); })
      .def("side_joins", [](const DCSlam& slam) { return event_dicts(slam.side_joins()); })
      .def("side_join_pairings", [](const DCSlam& slam) { return pairing_dicts(slam.side_joins()); })
      .def("tree_leaves",
           [](const DCSlam& slam) {
             py::list out;
             for (const TreeLeaf& leaf : slam.tree_leaves()) {
               py::dict record;
               record["x"] = Eigen::VectorXd(leaf.map->x());
               record["P"] = Eigen::MatrixXd(leaf.map->P());
               record["feature_ids"] = leaf.map->ids();
               record["robot_id"] = leaf.robot_id;
               // The log's size: steps (predicts) and the measurements kept from them.
               record["steps"] = leaf.log->u.size();
               record["measurements"] = leaf.log->measurements.size();
               out.append(record);
             }
             return out;
           })
      .def("stack_shape", &DCSlam::stack_shape)
      .def("finish_joins", &DCSlam::finish_joins, py::call_guard<py::gil_scoped_release>())
      .def("local_map_size", [](const DCSlam& slam) { return slam.local_map().map().num_features(); });
}

}  // namespace dcslam::bindings
