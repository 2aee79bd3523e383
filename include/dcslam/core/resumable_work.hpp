#pragma once
// The granularity of resumable work (docs/design.md §4.4, §5.3): computations that run in
// steps so that an amortized join spreads over many filter steps. A step is bounded by a work
// unit where the computation's sizes allow, and its boundaries depend on the sizes and the
// unit alone, never on how the steps are spread over calls, so a result is bitwise the same
// however it is sliced. These are the defaults of every option that sets a granularity.
#include <cstdint>

#include <Eigen/Core>

namespace dcslam {

// Multiply-adds that bound one step (JoinOptions::work_unit, RjcOptions::work_unit): small
// enough that an amortized step stays short when a join imposes hundreds of pairs.
inline constexpr std::int64_t kDefaultWorkUnit = std::int64_t{1} << 20;

// Width of the panels of a blocked Cholesky factorisation and of the column blocks a join
// writes its result in (JoinOptions::block_columns, RjcOptions::panel_width).
inline constexpr Eigen::Index kDefaultPanelWidth = 64;

}  // namespace dcslam
