#pragma once
// Data association between the two maps of a D&C join without ids (DESIGN.md §6): candidate
// pairs through a spatial hash over m1's features, individual compatibility with the pair
// covariance P_ii + P_jj - P_ij - P_ji, then JCBB over the whole overlap ("jcbb") or RJC
// (the paper's Algorithm 3, "rjc"). The individual gate only prunes, at a tenth of the
// decision gate's tail (0.999 for gate_confidence 0.99; the overlap counts features with a
// candidate at that level); pairs are accepted by the joint or conditional test at
// gate_confidence.
#include <utility>
#include <vector>

#include "dcslam/jcbb.hpp"
#include "dcslam/map_joining.hpp"

namespace dcslam {

// Measurement = feature j of the moved m2, feature = feature i of m1; the innovation of the
// pairing is f'_j - f_i, whose covariance is P_ii + P_jj - P_ij - P_ji in the stacked map,
// plus feature_sigma^2 I for each feature the two pairings share (each feature carries its
// own independent error of that size: SlamConfig::join_feature_sigma).
class JoinPairingModel : public PairingModel {
 public:
  explicit JoinPairingModel(const JoinFrame& frame, double feature_sigma = 0.0)
      : frame_(frame), feature_variance_(feature_sigma * feature_sigma) {}
  Vec2 innovation(const Pairing& p) const override;
  Mat2 covariance(const Pairing& a, const Pairing& b) const override;

 private:
  const JoinFrame& frame_;
  double feature_variance_;
};

struct JoinAssociationResult {
  std::vector<std::pair<Eigen::Index, Eigen::Index>> pairs;  // (i in m1, j in m2)
  int overlap = 0;
  int tries = 0;
};

JoinAssociationResult associate_maps(const JoinFrame& frame, const JoinOptions& options);

}  // namespace dcslam
