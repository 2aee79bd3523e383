#include "dcslam/core/input_checks.hpp"

#include <algorithm>
#include <cmath>
#include <string>
#include <unordered_set>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

// Relative: covariances come from users and from arithmetic on user data, so exact symmetry
// cannot be demanded.
constexpr double kSymmetryTolerance = 1e-9;

std::string argument(const char* function, const char* name) {
  return std::string(function) + ": argument '" + name + "'";
}

std::string indexed(const std::string& argument, std::size_t index) {
  return argument + "[" + std::to_string(index) + "]";
}

std::string bound_fault(double value, double bound, const char* unit) {
  if (std::fabs(value) <= bound) return {};
  return number_text(value) + " exceeds " + number_text(bound) + unit + " in magnitude";
}

template <typename Matrix>
bool is_symmetric(const Matrix& A) {
  const double scale = A.cwiseAbs().maxCoeff();
  return (A - A.transpose()).cwiseAbs().maxCoeff() <= kSymmetryTolerance * scale;
}

// The first entry beyond kMaxVariance, as "[i, j]: <fault>", or "".
template <typename Matrix>
std::string covariance_entries_fault(const Matrix& A) {
  for (Eigen::Index i = 0; i < A.rows(); ++i) {
    for (Eigen::Index j = 0; j < A.cols(); ++j) {
      std::string fault = covariance_entry_fault(A(i, j));
      if (!fault.empty()) return "[" + std::to_string(i) + ", " + std::to_string(j) + "]: " + fault;
    }
  }
  return {};
}

}  // namespace

std::string distance_fault(double value) { return bound_fault(value, kMaxDistance, " m"); }
std::string angle_fault(double value) { return bound_fault(value, kMaxAngle, " rad"); }
std::string covariance_entry_fault(double value) { return bound_fault(value, kMaxVariance, ""); }

std::string semidefinite_fault(const Mat3& Q) {
  if (!is_symmetric(Q)) return "is not symmetric";
  const Mat3 symmetric = 0.5 * (Q + Q.transpose());
  // Positive definite (the usual case) settles it; otherwise the eigenvalues decide within
  // the tolerance.
  if (Eigen::LLT<Mat3>(symmetric).info() == Eigen::Success) return {};
  const double smallest =
      Eigen::SelfAdjointEigenSolver<Mat3>(symmetric, Eigen::EigenvaluesOnly).eigenvalues().minCoeff();
  if (smallest >= -kSemiDefiniteTolerance) return {};
  return "is not positive semi-definite (smallest eigenvalue " + number_text(smallest) + ")";
}

std::string definite_fault(const Mat2& R) {
  if (!is_symmetric(R)) return "is not symmetric";
  const double off_diagonal = 0.5 * (R(0, 1) + R(1, 0));
  const double determinant = R(0, 0) * R(1, 1) - off_diagonal * off_diagonal;
  if (R(0, 0) > 0.0 && determinant > 0.0) return {};
  return "is not positive definite (determinant " + number_text(determinant) + ")";
}

void check_motion(const Vec3& u, const Mat3& Q, const char* function) {
  // Messages are built only on failure: these checks run on every step of a filter.
  const auto u_arg = [function] { return argument(function, "u"); };
  if (!u.allFinite()) throw InvalidArgument(u_arg() + " contains a non-finite value (NaN or inf)");
  for (Eigen::Index i = 0; i < 3; ++i) {
    const std::string fault = i < 2 ? distance_fault(u(i)) : angle_fault(u(i));
    if (!fault.empty()) throw InvalidArgument(indexed(u_arg(), static_cast<std::size_t>(i)) + ": " + fault);
  }
  const auto q = [function] { return argument(function, "Q"); };
  if (!Q.allFinite()) throw InvalidArgument(q() + " contains a non-finite value (NaN or inf)");
  std::string fault = covariance_entries_fault(Q);
  if (!fault.empty()) throw InvalidArgument(q() + fault);
  fault = semidefinite_fault(Q);
  if (!fault.empty()) throw InvalidArgument(q() + " " + fault);
}

void check_measurements(const MeasurementsRef& z, const std::vector<Mat2>& R,
                        const std::vector<std::int64_t>* landmark_ids,
                        ObservationModel observation, Association association,
                        const char* function) {
  const auto m = static_cast<std::size_t>(z.rows());
  const auto z_arg = [function] { return argument(function, "z"); };
  for (std::size_t i = 0; i < m; ++i) {
    const auto row = z.row(static_cast<Eigen::Index>(i));
    if (!row.allFinite()) {
      throw InvalidArgument(indexed(z_arg(), i) + " contains a non-finite value (NaN or inf)");
    }
    if (observation == ObservationModel::RangeBearing) {
      if (!(row(0) > 0.0)) {
        throw InvalidArgument(indexed(z_arg(), i) + " has a range that is not positive (" +
                              number_text(row(0)) + ")");
      }
      std::string fault = distance_fault(row(0));
      if (!fault.empty()) throw InvalidArgument(indexed(z_arg(), i) + ": range " + fault);
      fault = angle_fault(row(1));
      if (!fault.empty()) throw InvalidArgument(indexed(z_arg(), i) + ": bearing " + fault);
    } else {
      for (Eigen::Index c = 0; c < 2; ++c) {
        const std::string fault = distance_fault(row(c));
        if (!fault.empty()) throw InvalidArgument(indexed(z_arg(), i) + ": coordinate " + fault);
      }
    }
  }

  const auto r_arg = [function] { return argument(function, "R"); };
  if (R.size() != 1 && R.size() != m) {
    throw InvalidArgument(r_arg() + ": expected 1 or " + std::to_string(m) +
                          " matrices of shape (2, 2), got " + std::to_string(R.size()));
  }
  for (std::size_t i = 0; i < R.size(); ++i) {
    const Mat2& Ri = R[i];
    const auto name = [&] { return R.size() == 1 ? r_arg() : indexed(r_arg(), i); };
    if (!Ri.allFinite()) throw InvalidArgument(name() + " contains a non-finite value (NaN or inf)");
    std::string fault = covariance_entries_fault(Ri);
    if (!fault.empty()) throw InvalidArgument(name() + fault);
    fault = definite_fault(Ri);
    if (!fault.empty()) throw InvalidArgument(name() + " " + fault);
  }

  const auto ids_arg = [function] { return argument(function, "landmark_ids"); };
  if (association != Association::Known) {
    if (landmark_ids) {
      throw InvalidArgument(ids_arg() + " is only accepted in association mode 'known' (this filter uses '" +
                            to_string(association) + "')");
    }
    return;
  }
  if (!landmark_ids) throw InvalidArgument(ids_arg() + " is required in association mode 'known'");
  if (landmark_ids->size() != m) {
    throw InvalidArgument(ids_arg() + ": expected " + std::to_string(m) + " ids (one per row of z), got " +
                          std::to_string(landmark_ids->size()));
  }
  std::unordered_set<std::int64_t> seen;
  seen.reserve(m);
  for (std::size_t i = 0; i < m; ++i) {
    const std::int64_t id = (*landmark_ids)[i];
    if (id < -1) {
      throw InvalidArgument(indexed(ids_arg(), i) + " is " + std::to_string(id) +
                            " (ids are >= 0, or -1 for a measurement to reject)");
    }
    if (id != -1 && !seen.insert(id).second) {
      throw InvalidArgument(indexed(ids_arg(), i) + ": id " + std::to_string(id) +
                            " appears twice in one scan");
    }
  }
}

}  // namespace dcslam
