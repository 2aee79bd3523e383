#include "dcslam/association/pairing_exchanges.hpp"

#include <unordered_map>
#include <utility>

namespace dcslam {

namespace {

std::int64_t key_of(int measurement, int feature) {
  return (static_cast<std::int64_t>(measurement) << 32) | static_cast<std::uint32_t>(feature);
}

}  // namespace

std::int64_t exchange_crossed_pairings(const std::vector<std::tuple<double, int, int>>& scored,
                                       const std::vector<int>& movable, std::vector<int>& feature_of,
                                       int max_rounds) {
  std::unordered_map<std::int64_t, double> distance_of;
  std::unordered_map<int, std::vector<std::pair<int, double>>> candidates_of;
  distance_of.reserve(scored.size());
  for (const auto& [distance_sq, measurement, feature] : scored) {
    distance_of.emplace(key_of(measurement, feature), distance_sq);
    candidates_of[measurement].emplace_back(feature, distance_sq);
  }
  std::unordered_map<int, int> measurement_of;  // feature -> its movable measurement
  for (int measurement : movable) measurement_of[feature_of[static_cast<std::size_t>(measurement)]] = measurement;
  std::int64_t work = static_cast<std::int64_t>(scored.size());
  bool exchanged = true;
  for (int round = 0; exchanged && round < max_rounds; ++round) {
    exchanged = false;
    for (int m1 : movable) {
      const int f1 = feature_of[static_cast<std::size_t>(m1)];
      const double d11 = distance_of.at(key_of(m1, f1));
      const auto& candidates = candidates_of[m1];
      work += static_cast<std::int64_t>(candidates.size());
      for (const auto& [f2, d12] : candidates) {
        if (f2 == f1) continue;
        const auto owner = measurement_of.find(f2);
        if (owner == measurement_of.end()) continue;
        const int m2 = owner->second;
        const auto d21 = distance_of.find(key_of(m2, f1));
        if (d21 == distance_of.end()) continue;
        if (d12 + d21->second < d11 + distance_of.at(key_of(m2, f2))) {
          feature_of[static_cast<std::size_t>(m1)] = f2;
          feature_of[static_cast<std::size_t>(m2)] = f1;
          measurement_of[f2] = m1;
          measurement_of[f1] = m2;
          exchanged = true;
          break;
        }
      }
    }
  }
  return work;
}

}  // namespace dcslam
