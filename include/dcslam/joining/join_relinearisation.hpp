#pragma once
// The iterated join's linearisation point (docs/design.md §4.6, docs/divide_and_conquer.md):
// Gauss–Newton (and, once it has multipliers, Newton through Woodbury) on the constrained MAP
// over the variables the constraints involve, s = [R1; matched f_i; matched f_j], as
// resumable work: begin(), then unit() until converged(), then finish() moves the rest of m2.
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "dcslam/core/blocked_cholesky.hpp"
#include "dcslam/core/gaussian_map.hpp"
#include "dcslam/core/geometry.hpp"
#include "dcslam/joining/join_options.hpp"

namespace dcslam {

class JoinRelinearisation {
 public:
  using Pairs = std::vector<std::pair<Eigen::Index, Eigen::Index>>;

  // The point starts at the prior means (or options.linearisation, where it stays); steps are
  // taken when there are pairs and options.max_iterations > 1. The maps and pairs must
  // outlive the work.
  void begin(const GaussianMap& first, const GaussianMap& second, const Pairs& pairs,
             const JoinOptions& options);
  bool converged() const { return state_.converged; }
  int steps() const { return state_.steps; }
  // One unit of work (about options.work_unit multiply-adds); returns its work.
  std::int64_t unit();
  // Once converged: m2's whole state moved with the last multipliers. Returns the work.
  std::int64_t finish();

  // Linearisation points of the constraint update: 0 without pairs, else 1 + steps taken.
  int iterations() const { return iterations_; }
  // The point found (valid after finish()): R1 in m1's base, m2's state vector.
  const Vec3& first_robot() const { return first_robot_; }
  const Eigen::VectorXd& second_x() const { return second_x_; }
  // Frees the point and forgets the maps, once the join no longer needs them.
  void release();

 private:
  const GaussianMap* first_ = nullptr;
  const GaussianMap* second_ = nullptr;
  const Pairs* pairs_ = nullptr;
  Eigen::Index work_unit_ = 1;
  Eigen::Index block_columns_ = 2;
  int max_iterations_ = 1;
  int iterations_ = 0;
  Vec3 first_robot_ = Vec3::Zero();
  Eigen::VectorXd second_x_;
  struct State {  // kept between the units of the re-linearisation
    Eigen::VectorXd prior, point, multipliers;  // s0, s, λ of the last step
    Eigen::VectorXd dual;                       // g with s - s0 = P_ss g (H'λ at a KKT point)
    Eigen::MatrixXd covariance;                 // P_ss
    Eigen::Index gathered = 0;                  // columns of s0 and P_ss gathered so far
    Eigen::MatrixXd gain, factor;               // P_ss H' and S of this step, while built
    Eigen::VectorXd rhs;
    std::vector<Eigen::Matrix<double, 2, 3>> robot_jacobians;  // J_R of each pair, this step
    Eigen::Index next_build = 0;   // pairs done: < r of P_ss H', then r + those of S's rows
    bool factor_built = false;                  // the step's S is built (and being factored)
    ResumableCholesky cholesky;                 // of S, once built: L in its lower triangle
    Eigen::ArrayXd tolerance;
    std::vector<Eigen::Index> first_rows;       // rows of R1 and the matched f_i in m1
    std::vector<Eigen::Index> second_rows;      // rows of the matched f_j in m2
    Mat2 rotation = Mat2::Identity();           // R1's rotation where the last step linearised
    double moved = 0.0;                         // the last step, in units of tolerance
    int steps = 0;
    bool converged = true;
  } state_;
};

}  // namespace dcslam
