#include "dcslam/joining/online_localisation.hpp"

#include <algorithm>
#include <utility>

#include <Eigen/Cholesky>

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
// features, with the covariance of the chain and of newest together (first order). The
// Jacobian of newest's part is block diagonal (its robot's 3 x 3, each feature's rotation), so
// J Sigma J' costs O(n^2) for n kept rows, not the O(n^3) of a dense product.
GaussianMap moved_through_chain(const PoseLink& chain, const GaussianMap& newest, const std::vector<Index>& kept) {
  const auto p = static_cast<Index>(kept.size());
  GaussianMap moved = GaussianMap::uninitialized(p);
  const Index dim = moved.dim();
  Eigen::MatrixXd J_chain(dim, 3);  // of every moved element with respect to the chain
  std::vector<Index> rows{0, 1, 2};
  Mat3 J_robot_chain, J_robot;
  Mat2 J_point = Mat2::Identity();
  moved.x().head<3>() = compose(chain.mean, newest.robot(), &J_robot_chain, &J_robot);
  J_chain.topRows<3>() = J_robot_chain;
  for (Index k = 0; k < p; ++k) {
    const Index f = kept[static_cast<std::size_t>(k)];
    const Index row = GaussianMap::feature_offset(k);
    Mat23 J_pose;
    moved.x().segment<2>(row) = transform_point(chain.mean, newest.feature(f), &J_pose, &J_point);
    J_chain.middleRows<2>(row) = J_pose;
    moved.ids()[static_cast<std::size_t>(k)] = newest.ids()[static_cast<std::size_t>(f)];
    rows.push_back(GaussianMap::feature_offset(f));
    rows.push_back(GaussianMap::feature_offset(f) + 1);
  }
  // J_n P_n J_n' block by block (every feature's block is the chain's rotation): the rows
  // transformed, then, as J_n (J_n P_n)' is its transpose, the rows of the transpose; then the
  // chain's own J_c C J_c' (independent of newest).
  const auto transform_rows = [&](Eigen::MatrixXd& M) {
    M.topRows<3>() = (J_robot * M.topRows<3>()).eval();
    for (Index k = 0; k < p; ++k) {
      const Index row = GaussianMap::feature_offset(k);
      M.middleRows<2>(row) = (J_point * M.middleRows<2>(row)).eval();
    }
  };
  Eigen::MatrixXd P = newest.P()(rows, rows);
  transform_rows(P);
  P.transposeInPlace();
  transform_rows(P);
  moved.P() = P + J_chain * chain.covariance * J_chain.transpose();
  return moved;
}

}  // namespace

MapLocalisation::MapLocalisation(LocalisationInputs inputs) : inputs_(std::move(inputs)) {}

void MapLocalisation::move() {
  const GaussianMap& newest = *inputs_.newest;
  std::vector<Index> kept;
  for (Index f = 0; f < newest.num_features(); ++f) {
    if (std::find(inputs_.left_out.begin(), inputs_.left_out.end(), f) == inputs_.left_out.end()) kept.push_back(f);
  }
  stage_ = Stage::Done;
  if (kept.empty() || inputs_.oldest->num_features() == 0) return;
  moved_ = std::make_unique<GaussianMap>(moved_through_chain(compose_chain(inputs_.between), newest, kept));
  if (largest_std(moved_->P().topLeftCorner<2, 2>()) > inputs_.max_sigma) return;
  frame_ = std::make_unique<JoinFrame>(*inputs_.oldest, *moved_);
  if (inputs_.options.association == JoinAssociation::Known) {
    condition(associate_by_id(*inputs_.oldest, *moved_));
    return;
  }
  associator_ = std::make_unique<JoinAssociator>(*frame_, inputs_.options);
  stage_ = Stage::Associate;
}

namespace {

// Work in the association's units (about a multiply-add each; kPairingCovarianceUnits a
// covariance block): moving a map of dimension d through the chain, two passes of 2 x 2 blocks
// over its covariance and the chain's rank-3 term.
std::int64_t move_work(std::int64_t d) { return 8 * d * d; }
// Conditioning on r pairs: their joint covariance's blocks and its factor.
std::int64_t condition_work(std::int64_t r) { return kPairingCovarianceUnits * r * (r + 1) / 2 + 8 * r * r * r / 3; }

}  // namespace

std::int64_t MapLocalisation::step(std::int64_t budget) {
  switch (stage_) {
    case Stage::Move: {
      const std::int64_t d = inputs_.newest->dim();
      move();
      return move_work(d);
    }
    case Stage::Associate: {
      const std::int64_t spent = associator_->advance(budget);
      if (associator_->done()) stage_ = Stage::Condition;
      return std::max<std::int64_t>(1, spent);
    }
    case Stage::Condition: {
      const auto r = static_cast<std::int64_t>(associator_->result().pairs.size());
      condition(associator_->result().pairs);
      return condition_work(r);
    }
    case Stage::Done:
      break;
  }
  return 0;
}

std::int64_t MapLocalisation::remaining_work() const {
  const auto p = static_cast<std::int64_t>(inputs_.newest->num_features());
  switch (stage_) {
    case Stage::Move:
      // The association's work is known once its candidates are: until then, its preparation's.
      return move_work(inputs_.newest->dim()) +
             kPairingCovarianceUnits * (static_cast<std::int64_t>(inputs_.oldest->num_features()) + 2 * p) +
             condition_work(p);
    case Stage::Associate:
      return associator_->remaining_work() + condition_work(p);
    case Stage::Condition:
      return condition_work(static_cast<std::int64_t>(associator_->result().pairs.size()));
    case Stage::Done:
      break;
  }
  return 0;
}

void MapLocalisation::condition(const std::vector<std::pair<Index, Index>>& pairs) {
  stage_ = Stage::Done;
  if (static_cast<int>(pairs.size()) < kMinLocalisationPairs) return;
  const GaussianMap& oldest = *inputs_.oldest;
  const GaussianMap& moved = *moved_;
  const JoinFrame& frame = *frame_;
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
  if (factor.info() != Eigen::Success) return;
  Vec3 pose = frame.moved_second_robot() - C * factor.solve(h);
  pose.z() = wrap_angle(pose.z());
  result_ = LocalisedPose{pose, static_cast<int>(r)};
}

std::optional<LocalisedPose> localise_against(const GaussianMap& oldest, const std::vector<PoseLink>& between,
                                              const GaussianMap& newest, const std::vector<Index>& left_out,
                                              double max_sigma, const JoinOptions& options) {
  // Borrowed, not owned: the maps outlive this call.
  const auto borrow = [](const GaussianMap& map) { return std::shared_ptr<const GaussianMap>(&map, [](const GaussianMap*) {}); };
  MapLocalisation localisation(LocalisationInputs{borrow(oldest), between, borrow(newest), left_out, max_sigma, options});
  localisation.finish();
  return localisation.result();
}

}  // namespace dcslam
