#pragma once
// Where each element of m1 and m2 goes in a join's result (docs/design.md §4.5), fixed once the
// pairs are known: [R2' | F1 | F2' | Q1 | R1 | Q2'], matched features of m2 and tentative
// features left unmatched gone. And how J_2, the Jacobian of x_{B1 R1} ⊕ · w.r.t. m2's
// elements, acts on m2's layout: block-diagonal rotations of each (x, y), headings passed.
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"

namespace dcslam {

struct JoinLayout {
  using Pairs = std::vector<std::pair<Eigen::Index, Eigen::Index>>;

  JoinLayout() = default;
  // Tentative features (indices into m1's and m2's features) left unmatched by `pairs` are
  // dropped: deleting their rows and columns is their exact marginal, and the constraints
  // never involve them. R1 is kept as a past pose when `keep_first_robot`.
  JoinLayout(const GaussianMap& first, const GaussianMap& second, const Pairs& pairs,
             const std::vector<Eigen::Index>& first_tentative,
             const std::vector<Eigen::Index>& second_tentative, bool keep_first_robot);

  // m1's kept elements: features not dropped, then its past poses, then R1 when kept.
  std::vector<Eigen::Index> first_kept_rows;   // rows of P1
  std::vector<std::int64_t> first_kept_ids;    // of the kept features
  // m2's kept elements: the robot, then features neither matched nor dropped, then its poses.
  std::vector<Eigen::Index> second_kept_rows;  // rows of P2
  std::vector<std::int64_t> second_kept_ids;   // of the kept features
  // Ids of the dropped tentative features, of m1 then of m2.
  std::vector<std::int64_t> dropped_ids;

  // The result's rows are runs of consecutive kept elements of one map: robot R2', F1, F2',
  // Q1 and R1, Q2'.
  struct Segment {
    Eigen::Index out_begin = 0, size = 0;
    bool second = false;  // from m2 (else m1)
    Eigen::Index local_begin = 0;  // index into first_kept_rows or second_kept_rows
  };
  std::vector<Segment> segments;
  const Segment& segment_of(Eigen::Index out_row) const;
  Eigen::Index second_kept_features_end() const;  // local index of m2's first kept pose
};

// What J_2 does to element a of m2's layout [robot (3) | feature pairs up to features_end |
// poses (3 each)]: the x and y of a point or pose are rotated together, headings pass.
enum class SecondRole { X, Y, Heading };
SecondRole second_role(Eigen::Index a, Eigen::Index features_end);

// J_2 (its rotation is `rotation`) from the left (rows) or J_2' from the right (columns) on a
// block of m2's elements (all of them or the kept ones: the robot, feature pairs up to local
// index features_end, then poses) starting at local index `local_begin`. The block must not
// split an (x, y) pair: it starts on an x or a heading and ends after a y or a heading.
void rotate_second_rows(Eigen::Ref<Eigen::MatrixXd> block, const Mat2& rotation,
                        Eigen::Index local_begin, Eigen::Index features_end);
void rotate_second_columns(Eigen::Ref<Eigen::MatrixXd> block, const Mat2& rotation,
                           Eigen::Index local_begin, Eigen::Index features_end);

}  // namespace dcslam
