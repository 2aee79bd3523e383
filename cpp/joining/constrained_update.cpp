#include "dcslam/joining/constrained_update.hpp"

#include <algorithm>
#include <utility>

#include "dcslam/joining/join_cost.hpp"

namespace dcslam {

using Index = Eigen::Index;

// The constraints' P H', S = L L' and L^-1 h (O(n r + r^3)), linearised at the point the
// re-linearisation found.
ConstrainedUpdate::ConstrainedUpdate(const GaussianMap& first, const GaussianMap& second,
                                     const Pairs& pairs, const JoinLayout& layout,
                                     const JoinOptions& options, const Vec3& first_robot,
                                     const Eigen::VectorXd& second_x)
    : first_(first),
      second_(second),
      pairs_(pairs),
      layout_(layout),
      options_(options),
      frame_(first, second, first_robot, second_x),
      rotation_(frame_.rotation()) {
  const Index r = static_cast<Index>(pairs_.size());
  const auto& J_R = frame_.jacobian_first_robot();
  const Index d2k = static_cast<Index>(layout_.second_kept_rows.size());
  J_R_kept_.resize(d2k, 3);
  for (Index a = 0; a < d2k; ++a) {
    J_R_kept_.row(a) = J_R.row(layout_.second_kept_rows[static_cast<std::size_t>(a)]);
  }
  gain_.resize(first.dim() + second.dim(), 2 * r);
  whitened_h_.resize(2 * r);
}

// Columns of P H' (rows [all of m1 (d1); all of m2 (d2)]) and entries of h for the
// constraints f_i - f'_j of the next pairs; O(n) a pair.
std::int64_t ConstrainedUpdate::constrain_next_pairs(std::int64_t budget) {
  const GaussianMap& m1 = first_;
  const GaussianMap& m2 = second_;
  const Index d1 = m1.dim(), d2 = m2.dim();
  const Index r = static_cast<Index>(pairs_.size());
  const auto& J_R = frame_.jacobian_first_robot();
  const auto P1 = m1.P();
  const auto P2 = m2.P();
  const Mat3 P1_RR = P1.topLeftCorner<3, 3>();
  const auto A1 = P1.leftCols(3);  // cov(m1, R1)
  auto PHt_first = gain_.topRows(d1);
  auto PHt_second = gain_.bottomRows(d2);
  Eigen::MatrixXd second_col(d2, 2);
  const std::int64_t pair_work = join_cost::constrain(1, static_cast<std::int64_t>(gain_.rows()));
  const Index batch = std::clamp<Index>(static_cast<Index>(budget / std::max<std::int64_t>(1, pair_work)), 1,
                                        join_cost::kPairsPerUnit);
  const Index end = std::min<Index>(r, next_pair_ + batch);
  for (Index k = next_pair_; k < end; ++k) {
    const auto [i, j] = pairs_[static_cast<std::size_t>(k)];
    const Index oi = GaussianMap::feature_offset(i), oj = GaussianMap::feature_offset(j);
    const Eigen::Matrix<double, 2, 3> J_j = J_R.middleRows<2>(oj);
    PHt_first.middleCols<2>(2 * k).noalias() = P1.middleCols(oi, 2);
    PHt_first.middleCols<2>(2 * k).noalias() -= A1 * J_j.transpose();
    // cov(m2 rows, f'_j) = J_R P1_RR J_j' + J_2 P2[:, f_j] Rot'.
    second_col.noalias() = P2.middleCols(oj, 2) * rotation_.transpose();
    rotate_second_rows(second_col, rotation_, 0, GaussianMap::feature_offset(m2.num_features()));
    PHt_second.middleCols<2>(2 * k).noalias() = J_R * P1.block(0, oi, 3, 2);
    PHt_second.middleCols<2>(2 * k).noalias() -= J_R * (P1_RR * J_j.transpose());
    PHt_second.middleCols<2>(2 * k) -= second_col;
    whitened_h_.segment<2>(2 * k) = m1.feature(i) - frame_.moved_second_feature(j);
  }
  const std::int64_t pairs_done = end - next_pair_;
  next_pair_ = end;
  return join_cost::constrain(pairs_done, static_cast<std::int64_t>(gain_.rows()));
}

void ConstrainedUpdate::begin_factor() {
  const Index d1 = first_.dim();
  const Index r = static_cast<Index>(pairs_.size());
  Eigen::MatrixXd S(2 * r, 2 * r);
  for (Index a = 0; a < r; ++a) {
    const auto [i, j] = pairs_[static_cast<std::size_t>(a)];
    S.middleRows<2>(2 * a) = gain_.middleRows<2>(GaussianMap::feature_offset(i)) -
                             gain_.middleRows<2>(d1 + GaussianMap::feature_offset(j));
  }
  S = 0.5 * (S + S.transpose()).eval();
  cholesky_ = ResumableCholesky(std::move(S), options_.block_columns);
}

// One panel of S = L L' (ResumableCholesky); the order of operations is fixed, so slicing
// never changes the result.
std::int64_t ConstrainedUpdate::factor_next_panel() {
  const std::int64_t cost = factor_constraint_panel(cholesky_);
  if (cholesky_.done()) {
    cholesky_.matrix().triangularView<Eigen::Lower>().solveInPlace(whitened_h_);
    next_solve_row_ = 0;
  }
  return cost;
}

// W = P H' L^-T, in place, one block of rows at a time (rows are independent).
std::int64_t ConstrainedUpdate::solve_next_rows() {
  const Eigen::MatrixXd& factor = cholesky_.matrix();
  const Index r2 = factor.rows();
  const Index rows = std::min<Index>(
      join_cost::solve_rows_per_unit(options_.work_unit, options_.block_columns,
                                     static_cast<Index>(pairs_.size())),
      gain_.rows() - next_solve_row_);
  if (r2 > 0) {
    auto block = gain_.middleRows(next_solve_row_, rows);
    factor.triangularView<Eigen::Lower>().transpose().solveInPlace<Eigen::OnTheRight>(block);
  }
  next_solve_row_ += rows;
  return static_cast<std::int64_t>(rows) * join_cost::solve_row(static_cast<std::int64_t>(pairs_.size()));
}

// The result's means and the low-rank factors of the fill (see the header), O(n r) in all,
// a block of output rows per unit of work: output row o belongs to a segment of m1's or m2's
// kept elements, and each row only reads its own row of P H' (now W).
void ConstrainedUpdate::begin_assemble() {
  const GaussianMap& m1 = first_;
  const GaussianMap& m2 = second_;
  const Index d1k = static_cast<Index>(layout_.first_kept_rows.size());
  const Index d2k = static_cast<Index>(layout_.second_kept_rows.size());
  const Index d1f = 2 * static_cast<Index>(layout_.first_kept_ids.size());
  const Index d2f = 2 * static_cast<Index>(layout_.second_kept_ids.size());
  const Index k = 2 * static_cast<Index>(pairs_.size());
  const Index out_dim = d1k + d2k;
  const Index poses = (d1k - d1f + d2k - 3 - d2f) / GaussianMap::kPoseDim;
  result_ = GaussianMap::uninitialized((d1f + d2f) / GaussianMap::kFeatureDim, poses);
  correction_.left.resize(out_dim, 6 + k);
  correction_.right_second.resize(d2k, 3 + k);
  correction_.right_first.resize(d1k, 3 + k);
  auto& ids = result_.ids();
  std::copy(layout_.first_kept_ids.begin(), layout_.first_kept_ids.end(), ids.begin());
  std::copy(layout_.second_kept_ids.begin(), layout_.second_kept_ids.end(),
            ids.begin() + static_cast<std::ptrdiff_t>(layout_.first_kept_ids.size()));
  std::vector<std::int64_t> pose_ids = m1.pose_ids();
  if (options_.keep_first_robot) pose_ids.push_back(options_.first_robot_id);
  pose_ids.insert(pose_ids.end(), m2.pose_ids().begin(), m2.pose_ids().end());
  result_.pose_ids() = std::move(pose_ids);
  next_assemble_row_ = 0;
  next_prefault_column_ = 0;
}

std::int64_t ConstrainedUpdate::prefault_next() {
  const Index second_columns = correction_.right_second.cols();
  const bool second = next_prefault_column_ < second_columns;
  Eigen::MatrixXd& factor = second ? correction_.right_second : correction_.right_first;
  const Index begin = second ? next_prefault_column_ : next_prefault_column_ - second_columns;
  const Index columns = std::min(factor.cols() - begin,
                                 join_cost::prefault_columns_per_unit(options_.work_unit, factor.rows()));
  factor.middleCols(begin, columns).setZero();
  next_prefault_column_ += columns;
  return join_cost::prefault(columns, factor.rows());
}

std::int64_t ConstrainedUpdate::assemble_next_rows() {
  if (next_prefault_column_ < correction_.right_second.cols() + correction_.right_first.cols()) {
    return prefault_next();
  }
  const GaussianMap& m1 = first_;
  const GaussianMap& m2 = second_;
  const JoinFrame& frame = frame_;
  const Index d1 = m1.dim();
  const Index first_features_end = 2 * static_cast<Index>(layout_.first_kept_ids.size());
  const Index second_features_end = layout_.second_kept_features_end();
  const Index second_poses_begin = GaussianMap::feature_offset(m2.num_features());
  const Index k = 2 * static_cast<Index>(pairs_.size());
  const Index out_dim = result_.dim();
  const auto P1 = m1.P();
  const Mat3 P1_RR = P1.topLeftCorner<3, 3>();
  const Eigen::VectorXd& v = whitened_h_;
  auto x = result_.x();
  const Index rows = join_cost::assemble_rows_per_unit(options_.work_unit, k);
  const Index end = std::min(out_dim, next_assemble_row_ + rows);
  // Runs of rows whose sources are consecutive rows of one input are copied as blocks: a row
  // at a time, the reads of the column-major W and the writes of N were one cache miss each.
  for (Index o = next_assemble_row_; o < end;) {
    const JoinLayout::Segment& segment = layout_.segment_of(o);
    const Index a = segment.local_begin + (o - segment.out_begin);
    const std::vector<Index>& kept =
        segment.second ? layout_.second_kept_rows : layout_.first_kept_rows;
    const Index src = kept[static_cast<std::size_t>(a)];
    Index length = 1;
    const Index segment_end = std::min(end, segment.out_begin + segment.size);
    while (o + length < segment_end && kept[static_cast<std::size_t>(a + length)] == src + length) {
      ++length;
    }
    auto L = correction_.left.middleRows(o, length);
    auto xs = x.segment(o, length);
    if (!segment.second) {  // m1 elements: L = [A1 | W | 0], N = [-W | A1]
      const auto W = gain_.middleRows(src, length);
      L.leftCols<3>() = P1.block(src, 0, length, 3);
      L.middleCols(3, k) = W;
      L.rightCols<3>().setZero();
      correction_.right_first.block(a, 0, length, k) = -W;
      correction_.right_first.block(a, k, length, 3) = P1.block(src, 0, length, 3);
      xs = m1.x().segment(src, length);
      xs.noalias() -= W * v;
      // The headings of m1's poses (and of R1) are corrected too: wrapped again.
      for (Index e = 0; e < length; ++e) {
        if (a + e >= first_features_end && (a + e - first_features_end) % 3 == 2) xs(e) = wrap_angle(xs(e));
      }
    } else {  // m2's robot, features or poses: L = [J_R P1_RR | W | J_R], N = [J_R | -W]
      const auto W = gain_.middleRows(d1 + src, length);
      const auto J = J_R_kept_.middleRows(a, length);
      L.leftCols<3>().noalias() = J * P1_RR;
      L.middleCols(3, k) = W;
      L.rightCols<3>() = J;
      correction_.right_second.block(a, 0, length, 3) = J;
      correction_.right_second.block(a, 3, length, k) = -W;
      for (Index e = 0; e < length; ++e) {
        const Index s = src + e;
        if (s >= 3 && s < second_poses_begin) {
          xs(e) = frame.moved_second_feature((s - 3) / 2)((s - 3) % 2);
        } else {
          const Index offset = s < 3 ? 0 : s - (s - second_poses_begin) % 3;
          xs(e) = frame.moved_second_pose(offset)(s - offset);
        }
      }
      xs.noalias() -= W * v;
      for (Index e = 0; e < length; ++e) {
        if (second_role(a + e, second_features_end) == SecondRole::Heading) xs(e) = wrap_angle(xs(e));
      }
    }
    o += length;
  }
  const std::int64_t done = end - next_assemble_row_;
  next_assemble_row_ = end;
  if (end == out_dim) gain_ = Eigen::MatrixXd();
  return done * join_cost::assemble_row(static_cast<std::int64_t>(pairs_.size())) + 1;
}

}  // namespace dcslam
