#include "dcslam/input_checks.hpp"

#include <algorithm>
#include <string>
#include <unordered_set>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "dcslam/errors.hpp"

namespace dcslam {

namespace {

// Relative tolerances: covariances come from users and from arithmetic on user data, so
// exact symmetry cannot be demanded, and a "zero" eigenvalue may come out as -1e-17.
constexpr double kSymmetryTolerance = 1e-9;
constexpr double kSemiDefiniteTolerance = 1e-12;

std::string argument(const char* function, const char* name) {
  return std::string(function) + ": argument '" + name + "'";
}

std::string indexed(const std::string& argument, std::size_t index) {
  return argument + "[" + std::to_string(index) + "]";
}

template <typename Matrix>
bool is_symmetric(const Matrix& A) {
  const double scale = A.cwiseAbs().maxCoeff();
  return (A - A.transpose()).cwiseAbs().maxCoeff() <= kSymmetryTolerance * scale;
}

}  // namespace

void check_motion(const Vec3& u, const Mat3& Q, const char* function) {
  if (!u.allFinite()) {
    throw InvalidArgument(argument(function, "u") + " contains a non-finite value (NaN or inf)");
  }
  // Messages are built only on failure: these checks run on every step of a filter.
  const auto q = [function] { return argument(function, "Q"); };
  if (!Q.allFinite()) throw InvalidArgument(q() + " contains a non-finite value (NaN or inf)");
  if (!is_symmetric(Q)) throw InvalidArgument(q() + " is not symmetric");
  const Mat3 symmetric = 0.5 * (Q + Q.transpose());
  // Positive definite (the usual case) settles it; otherwise the eigenvalues decide within
  // the tolerance.
  if (Eigen::LLT<Mat3>(symmetric).info() == Eigen::Success) return;
  const Vec3 eigenvalues = Eigen::SelfAdjointEigenSolver<Mat3>(symmetric, Eigen::EigenvaluesOnly)
                               .eigenvalues();
  const double scale = eigenvalues.cwiseAbs().maxCoeff();
  if (eigenvalues.minCoeff() < -kSemiDefiniteTolerance * scale) {
    throw InvalidArgument(q() + " is not positive semi-definite (smallest eigenvalue " +
                          std::to_string(eigenvalues.minCoeff()) + ")");
  }
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
    if (observation == ObservationModel::RangeBearing && !(row(0) > 0.0)) {
      throw InvalidArgument(indexed(z_arg(), i) + " has a range that is not positive");
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
    if (!is_symmetric(Ri)) throw InvalidArgument(name() + " is not symmetric");
    const double off_diagonal = 0.5 * (Ri(0, 1) + Ri(1, 0));
    if (!(Ri(0, 0) > 0.0 && Ri(0, 0) * Ri(1, 1) - off_diagonal * off_diagonal > 0.0)) {
      throw InvalidArgument(name() + " is not positive definite");
    }
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
