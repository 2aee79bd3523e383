#include "dcslam/joining/join_layout.hpp"

#include <stdexcept>
#include <string>

namespace dcslam {

using Index = Eigen::Index;

JoinLayout::JoinLayout(const GaussianMap& first, const GaussianMap& second, const Pairs& pairs,
                       const std::vector<Index>& first_tentative,
                       const std::vector<Index>& second_tentative, bool keep_first_robot) {
  const GaussianMap& m1 = first;
  const GaussianMap& m2 = second;
  std::vector<char> dropped(static_cast<std::size_t>(m1.num_features()), 0);
  for (Index i : first_tentative) dropped[static_cast<std::size_t>(i)] = 1;
  for (const auto& pair : pairs) dropped[static_cast<std::size_t>(pair.first)] = 0;
  for (Index i = 0; i < m1.num_features(); ++i) {
    const std::int64_t id = m1.ids()[static_cast<std::size_t>(i)];
    if (dropped[static_cast<std::size_t>(i)]) {
      dropped_ids.push_back(id);
      continue;
    }
    first_kept_rows.push_back(GaussianMap::feature_offset(i));
    first_kept_rows.push_back(GaussianMap::feature_offset(i) + 1);
    first_kept_ids.push_back(id);
  }
  // Past poses are never associated: m1's stay as they are, R1 joins them when kept.
  for (Index q = 0; q < m1.num_poses(); ++q) {
    for (Index c = 0; c < GaussianMap::kPoseDim; ++c) first_kept_rows.push_back(m1.pose_offset(q) + c);
  }
  if (keep_first_robot) {
    for (Index c = 0; c < GaussianMap::kRobotDim; ++c) first_kept_rows.push_back(c);
  }
  std::vector<char> second_dropped(static_cast<std::size_t>(m2.num_features()), 0);
  for (Index j : second_tentative) second_dropped[static_cast<std::size_t>(j)] = 1;
  for (const auto& pair : pairs) second_dropped[static_cast<std::size_t>(pair.second)] = 0;
  for (Index j = 0; j < m2.num_features(); ++j) {
    if (second_dropped[static_cast<std::size_t>(j)]) dropped_ids.push_back(m2.ids()[static_cast<std::size_t>(j)]);
  }

  std::vector<char> matched(static_cast<std::size_t>(m2.num_features()), 0);
  for (const auto& pair : pairs) matched[static_cast<std::size_t>(pair.second)] = 1;
  second_kept_rows = {0, 1, 2};
  for (Index j = 0; j < m2.num_features(); ++j) {
    if (matched[static_cast<std::size_t>(j)] || second_dropped[static_cast<std::size_t>(j)]) continue;
    second_kept_rows.push_back(GaussianMap::feature_offset(j));
    second_kept_rows.push_back(GaussianMap::feature_offset(j) + 1);
    second_kept_ids.push_back(m2.ids()[static_cast<std::size_t>(j)]);
  }
  for (Index q = 0; q < m2.num_poses(); ++q) {
    for (Index c = 0; c < GaussianMap::kPoseDim; ++c) second_kept_rows.push_back(m2.pose_offset(q) + c);
  }

  const Index d1k = static_cast<Index>(first_kept_rows.size());
  const Index d2k = static_cast<Index>(second_kept_rows.size());
  const Index d1f = 2 * static_cast<Index>(first_kept_ids.size());
  const Index d2f = 2 * static_cast<Index>(second_kept_ids.size());
  segments = {Segment{0, 3, true, 0}, Segment{3, d1f, false, 0}, Segment{3 + d1f, d2f, true, 3},
              Segment{3 + d1f + d2f, d1k - d1f, false, d1f},
              Segment{3 + d1k + d2f, d2k - 3 - d2f, true, 3 + d2f}};
}

const JoinLayout::Segment& JoinLayout::segment_of(Index out_row) const {
  for (const Segment& segment : segments) {
    if (out_row >= segment.out_begin && out_row < segment.out_begin + segment.size) return segment;
  }
  throw std::logic_error("MapJoin: output row " + std::to_string(out_row) + " out of range");
}

Index JoinLayout::second_kept_features_end() const {
  return GaussianMap::feature_offset(static_cast<Index>(second_kept_ids.size()));
}

SecondRole second_role(Index a, Index features_end) {
  if (a >= 3 && a < features_end) return (a - 3) % 2 == 0 ? SecondRole::X : SecondRole::Y;
  const Index component = a < 3 ? a : (a - features_end) % 3;
  return component == 0 ? SecondRole::X : component == 1 ? SecondRole::Y : SecondRole::Heading;
}

void rotate_second_rows(Eigen::Ref<Eigen::MatrixXd> block, const Mat2& rotation, Index local_begin,
                        Index features_end) {
  const double c = rotation(0, 0), s = rotation(1, 0);
  for (Index a = 0; a < block.rows(); ++a) {
    if (second_role(local_begin + a, features_end) != SecondRole::X) continue;
    for (Index col = 0; col < block.cols(); ++col) {
      const double u = block(a, col), w = block(a + 1, col);
      block(a, col) = c * u - s * w;
      block(a + 1, col) = s * u + c * w;
    }
    ++a;
  }
}

void rotate_second_columns(Eigen::Ref<Eigen::MatrixXd> block, const Mat2& rotation,
                           Index local_begin, Index features_end) {
  const double c = rotation(0, 0), s = rotation(1, 0);
  for (Index a = 0; a < block.cols(); ++a) {
    if (second_role(local_begin + a, features_end) != SecondRole::X) continue;
    for (Index row = 0; row < block.rows(); ++row) {
      const double u = block(row, a), w = block(row, a + 1);
      block(row, a) = c * u - s * w;
      block(row, a + 1) = s * u + c * w;
    }
    ++a;
  }
}

}  // namespace dcslam
