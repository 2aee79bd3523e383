#include "dcslam/core/gaussian_map.hpp"

#include <algorithm>
#include <string>

#include "dcslam/core/errors.hpp"

namespace dcslam {

GaussianMap::GaussianMap() : x_(Eigen::VectorXd::Zero(32)), P_(Eigen::MatrixXd::Zero(32, 32)) {}

void GaussianMap::mirror_lower_triangle() {
  auto P = this->P();
  const Index n = P.rows();
  // Square tiles keep both the read (column-major, lower) and the write (upper) cache-friendly.
  constexpr Index kTile = 64;
  for (Index j0 = 0; j0 < n; j0 += kTile) {
    const Index width = std::min(kTile, n - j0);
    for (Index j = j0; j < j0 + width; ++j) {
      for (Index i = j0; i < j; ++i) P(i, j) = P(j, i);
    }
    for (Index i0 = j0 + width; i0 < n; i0 += kTile) {
      const Index height = std::min(kTile, n - i0);
      P.block(j0, i0, width, height) = P.block(i0, j0, height, width).transpose();
    }
  }
}

namespace {
void require_no_poses(Eigen::Index poses, const char* function) {
  if (poses > 0) {
    throw InvalidArgument(std::string("GaussianMap::") + function +
                          ": the map holds past poses, it cannot grow or reorder its features");
  }
}
}  // namespace

GaussianMap GaussianMap::uninitialized(Index num_features, Index num_poses) {
  if (num_features < 0 || num_poses < 0) {
    throw InvalidArgument("GaussianMap::uninitialized: negative size (" +
                          std::to_string(num_features) + " features, " +
                          std::to_string(num_poses) + " poses)");
  }
  const Index dim = kRobotDim + kFeatureDim * num_features + kPoseDim * num_poses;
  GaussianMap map;
  map.x_.resize(dim);
  map.P_.resize(dim, dim);
  map.dim_ = dim;
  map.ids_.assign(static_cast<std::size_t>(num_features), -1);
  map.pose_ids_.assign(static_cast<std::size_t>(num_poses), -1);
  return map;
}

Eigen::MatrixXd GaussianMap::release_covariance() {
  Eigen::MatrixXd covariance;
  if (P_.rows() == dim_) {
    covariance.swap(P_);
  } else {
    covariance = P_.topLeftCorner(dim_, dim_);
  }
  *this = GaussianMap();
  return covariance;
}

void GaussianMap::reserve(Index dim) {
  if (dim <= capacity()) return;
  Index capacity = std::max<Index>(32, P_.rows());
  // Growth by half: amortised O(1) copies per element, and storage at most 2.25x the
  // covariance (doubling would allow 4x, P being square).
  while (capacity < dim) capacity += capacity / 2;
  Eigen::VectorXd x = Eigen::VectorXd::Zero(capacity);
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(capacity, capacity);
  x.head(dim_) = x_.head(dim_);
  P.topLeftCorner(dim_, dim_) = P_.topLeftCorner(dim_, dim_);
  x_.swap(x);
  P_.swap(P);
}

void GaussianMap::resize(Index dim) {
  require_no_poses(num_poses(), "resize");
  if (dim < kRobotDim || (dim - kRobotDim) % kFeatureDim != 0) {
    throw InvalidArgument("GaussianMap::resize: dimension " + std::to_string(dim) +
                          " is not 3 + 2n");
  }
  reserve(dim);
  if (dim > dim_) {
    x_.segment(dim_, dim - dim_).setZero();
    P_.block(0, dim_, dim, dim - dim_).setZero();
    P_.block(dim_, 0, dim - dim_, dim_).setZero();
  }
  dim_ = dim;
  ids_.resize(static_cast<std::size_t>(num_features()), -1);
}

GaussianMap::Index GaussianMap::append_feature(const Vec2& mean, std::int64_t id) {
  require_no_poses(num_poses(), "append_feature");
  const Index k = num_features();
  resize(dim_ + kFeatureDim);
  x_.segment<2>(feature_offset(k)) = mean;
  ids_[static_cast<std::size_t>(k)] = id;
  return k;
}

void GaussianMap::remove_features(std::vector<Index> indices) {
  if (indices.empty()) return;
  std::sort(indices.begin(), indices.end());
  const Index n = num_features();
  std::vector<char> removed(static_cast<std::size_t>(n), 0);
  for (Index k : indices) {
    if (k < 0 || k >= n || removed[static_cast<std::size_t>(k)]) {
      throw InvalidArgument("GaussianMap::remove_features: bad feature index " +
                            std::to_string(k));
    }
    removed[static_cast<std::size_t>(k)] = 1;
  }
  // Source index of each kept state component, in order.
  std::vector<Index> keep;
  keep.reserve(static_cast<std::size_t>(dim_));
  for (Index i = 0; i < kRobotDim; ++i) keep.push_back(i);
  std::vector<std::int64_t> kept_ids;
  for (Index k = 0; k < n; ++k) {
    if (removed[static_cast<std::size_t>(k)]) continue;
    keep.push_back(feature_offset(k));
    keep.push_back(feature_offset(k) + 1);
    kept_ids.push_back(ids_[static_cast<std::size_t>(k)]);
  }
  for (Index i = pose_offset(0); i < dim_; ++i) keep.push_back(i);
  const Index new_dim = static_cast<Index>(keep.size());
  // Columns move left and rows move up (keep[i] >= i), so one in-place forward pass is safe.
  for (Index j = 0; j < new_dim; ++j) {
    const Index src_col = keep[static_cast<std::size_t>(j)];
    for (Index i = 0; i < new_dim; ++i) P_(i, j) = P_(keep[static_cast<std::size_t>(i)], src_col);
    x_(j) = x_(src_col);
  }
  dim_ = new_dim;
  ids_ = std::move(kept_ids);
}

GaussianMap::Index GaussianMap::swap_remove_feature(Index k) {
  require_no_poses(num_poses(), "swap_remove_feature");
  const Index n = num_features();
  if (k < 0 || k >= n) {
    throw InvalidArgument("GaussianMap::swap_remove_feature: bad feature index " + std::to_string(k));
  }
  const Index last = n - 1;
  if (k != last) {
    const Index to = feature_offset(k), from = feature_offset(last);
    // Columns first (every row but the two moving blocks), then the diagonal block, then the
    // rows as the mirror of the columns: P stays symmetric.
    for (Index j = 0; j < dim_; ++j) {
      if (j >= to && j < to + kFeatureDim) continue;
      P_.block<2, 1>(to, j) = P_.block<2, 1>(from, j);
    }
    P_.block<2, 2>(to, to) = P_.block<2, 2>(from, from);
    for (Index j = 0; j < dim_; ++j) {
      if (j >= to && j < to + kFeatureDim) continue;
      P_.block<1, 2>(j, to) = P_.block<2, 1>(to, j).transpose();
    }
    x_.segment<2>(to) = x_.segment<2>(from);
    ids_[static_cast<std::size_t>(k)] = ids_[static_cast<std::size_t>(last)];
  }
  dim_ -= kFeatureDim;
  ids_.pop_back();
  return k == last ? -1 : last;
}

}  // namespace dcslam
