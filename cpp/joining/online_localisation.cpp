#include "dcslam/joining/online_localisation.hpp"

#include <algorithm>
#include <utility>

#include <Eigen/Cholesky>

#include "dcslam/joining/join_association.hpp"
#include "dcslam/joining/join_frame.hpp"

namespace dcslam {

namespace {

using Index = Eigen::Index;

// Fewer pairs than this leave the pose as the chain has it. One or two pairs pin the position
// poorly and are often clutter: on the simulated lawn (seed 0) such localisations moved the
// pose by 1-4 m; with neither this floor nor the sigma cap the lawns' largest online errors
// (5 seeds) rose from 2.2 / 2.7 m to 4.2 / 6.1 m (docs/divide_and_conquer.md).
constexpr int kMinLocalisationPairs = 5;

// The chain's composed pose and its covariance, first order.
PoseLink compose_chain(const std::vector<PoseLink>& between) {
  PoseLink chain;
  for (const PoseLink& link : between) {
    Mat3 J_chain, J_link;
    chain.mean = compose(chain.mean, link.mean, &J_chain, &J_link);
    chain.covariance = J_chain * chain.covariance * J_chain.transpose() + J_link * link.covariance * J_link.transpose();
  }
  return chain;
}

// `newest` moved through the chain into oldest's robot frame: its robot and its kept
// features, with the covariance of the chain and of newest together (first order).
GaussianMap moved_through_chain(const PoseLink& chain, const GaussianMap& newest, const std::vector<Index>& kept) {
  const auto p = static_cast<Index>(kept.size());
  GaussianMap moved = GaussianMap::uninitialized(p);
  // J maps [chain (3); newest's robot (3); its kept features (2 each)] to the moved state.
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(moved.dim(), 6 + 2 * p);
  Mat3 J_chain, J_robot;
  moved.x().head<3>() = compose(chain.mean, newest.robot(), &J_chain, &J_robot);
  J.block<3, 3>(0, 0) = J_chain;
  J.block<3, 3>(0, 3) = J_robot;
  for (Index k = 0; k < p; ++k) {
    Mat23 J_pose;
    Mat2 J_point;
    const Index row = GaussianMap::feature_offset(k);
    moved.x().segment<2>(row) = transform_point(chain.mean, newest.feature(kept[static_cast<std::size_t>(k)]), &J_pose, &J_point);
    J.block<2, 3>(row, 0) = J_pose;
    J.block<2, 2>(row, 6 + 2 * k) = J_point;
    moved.ids()[static_cast<std::size_t>(k)] = newest.ids()[static_cast<std::size_t>(kept[static_cast<std::size_t>(k)])];
  }
  // The covariance of [chain; newest's robot and kept features]: the chain is independent.
  std::vector<Index> rows{0, 1, 2};
  for (Index f : kept) {
    rows.push_back(GaussianMap::feature_offset(f));
    rows.push_back(GaussianMap::feature_offset(f) + 1);
  }
  const auto n = static_cast<Index>(rows.size());
  Eigen::MatrixXd sigma = Eigen::MatrixXd::Zero(3 + n, 3 + n);
  sigma.topLeftCorner<3, 3>() = chain.covariance;
  sigma.bottomRightCorner(n, n) = newest.P()(rows, rows);
  moved.P() = J * sigma * J.transpose();
  return moved;
}

}  // namespace

std::optional<LocalisedPose> localise_against(const GaussianMap& oldest, const std::vector<PoseLink>& between,
                                              const GaussianMap& newest, const std::vector<Index>& left_out,
                                              double max_sigma, const JoinOptions& options) {
  std::vector<Index> kept;
  for (Index f = 0; f < newest.num_features(); ++f) {
    if (std::find(left_out.begin(), left_out.end(), f) == left_out.end()) kept.push_back(f);
  }
  if (kept.empty() || oldest.num_features() == 0) return std::nullopt;
  const GaussianMap moved = moved_through_chain(compose_chain(between), newest, kept);
  if (largest_std(moved.P().topLeftCorner<2, 2>()) > max_sigma) return std::nullopt;
  const JoinFrame frame(oldest, moved);
  const std::vector<std::pair<Index, Index>> pairs =
      options.association == JoinAssociation::Known ? associate_by_id(oldest, moved) : associate_maps(frame, options).pairs;
  if (static_cast<int>(pairs.size()) < kMinLocalisationPairs) return std::nullopt;

  // Condition the moved robot g = R1 ⊕ s_R on the constraints h_a = f_i - R1 ⊕ s_j = 0:
  // g - C_gh S_h^-1 h, with C_gh and S_h from the two maps' covariances (independent).
  const auto r = static_cast<Index>(pairs.size());
  Eigen::VectorXd h(2 * r);
  Eigen::MatrixXd S(2 * r, 2 * r);
  Eigen::MatrixXd C(3, 2 * r);
  const auto P1 = oldest.P();
  const auto P2 = moved.P();
  const Mat3 J_first_robot = frame.jacobian_first_robot().topRows<3>();
  Mat3 J_second_robot = Mat3::Identity();
  J_second_robot.topLeftCorner<2, 2>() = frame.rotation();
  for (Index a = 0; a < r; ++a) {
    const auto [i, j] = pairs[static_cast<std::size_t>(a)];
    h.segment<2>(2 * a) = frame.first_feature(i) - frame.moved_second_feature(j);
    for (Index b = 0; b <= a; ++b) {
      const auto [k, l] = pairs[static_cast<std::size_t>(b)];
      S.block<2, 2>(2 * a, 2 * b) = frame.constraint_covariance(i, j, k, l);
      S.block<2, 2>(2 * b, 2 * a) = S.block<2, 2>(2 * a, 2 * b).transpose();
    }
    const Mat23 J_first_point = frame.jacobian_first_robot().middleRows<2>(GaussianMap::feature_offset(j));
    const Eigen::Matrix<double, 3, 2> first_part =
        P1.block<3, 2>(0, GaussianMap::feature_offset(i)) - P1.topLeftCorner<3, 3>() * J_first_point.transpose();
    C.middleCols<2>(2 * a) = J_first_robot * first_part -
                             J_second_robot * P2.block<3, 2>(0, GaussianMap::feature_offset(j)) * frame.rotation().transpose();
  }
  const Eigen::LLT<Eigen::MatrixXd> factor(S);
  if (factor.info() != Eigen::Success) return std::nullopt;
  Vec3 pose = frame.moved_second_robot() - C * factor.solve(h);
  pose.z() = wrap_angle(pose.z());
  return LocalisedPose{pose, static_cast<int>(r)};
}

}  // namespace dcslam
