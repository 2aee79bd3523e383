#pragma once
// A PairingModel conditioned on pairings already accepted: the chain rule of the joint
// compatibility test, one pairing at a time (docs/data_association.md). With the kept
// pairings K, their stacked innovation nu_K and joint covariance S_K = L L',
//   nu_a|K  = nu_a  - C_aK S_K^-1 nu_K  = nu_a  - w_a' (L^-1 nu_K),
//   C_ab|K  = C_ab  - C_aK S_K^-1 C_Kb  = C_ab  - w_a' w_b,        w_a = L^-1 C_Ka,
// and the joint D^2 of K is the sum of each kept pairing's distance conditioned on those
// kept before it. The factor L grows by one 2-row block per kept pairing, O(|K|^2), whether
// kept one at a time (keep_if_within()) or a panel at a time (keep_each_within()).
#include <cstdint>
#include <unordered_map>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

class ConditionedPairingModel : public PairingModel {
 public:
  // `base` must outlive the model. `expected_pairings` only sizes the factor ahead.
  explicit ConditionedPairingModel(const PairingModel& base, Eigen::Index expected_pairings = 0);

  // PairingModel, conditioned on the kept pairings. Each pairing's w_a is computed once
  // (O(|K|) covariance blocks and a triangular solve, O(|K|^2)) and cached until the next
  // keep(), so that a search over a few pairings conditioned on many costs O(|K|) a block.
  // Not thread-safe (the cache).
  Vec2 innovation(const Pairing& pairing) const override;
  Mat2 covariance(const Pairing& a, const Pairing& b) const override;

  // Adds `pairing` to K if its conditional covariance C_aa|K is positive definite and its D^2
  // conditioned on K is at most `gate` (infinity: positive definite is enough); false and K
  // unchanged otherwise. O(|K|^2), computed afresh (not from the cache).
  bool keep_if_within(const Pairing& pairing, double gate);
  // keep_if_within() on each of `pairings` in turn, with gates[i] for pairings[i], until
  // `max_rejections` were refused; returns how many it tested, kept[i] saying whether
  // pairings[i] was kept. The same test, up to rounding, but with one triangular solve of L
  // for all of them (w_a for the panel at once, then the panel's pairings conditioned on each
  // other through a factor of at most 2 |pairings| rows): a pairing conditioned on many reads
  // L once for the panel, not once a pairing, which is what the solve is bound by.
  std::size_t keep_each_within(const std::vector<Pairing>& pairings, const std::vector<double>& gates,
                               int max_rejections, std::vector<char>& kept);
  // D^2 of `pairing` conditioned on K (infinity if C_aa|K is not positive definite).
  double conditional_distance_sq(const Pairing& pairing);

  // Caches the conditioned cross term of each of `pairings` not cached yet, with one triangular
  // solve for all of them: a candidate list gated at once reads the factor L once, not once a
  // candidate (the solve of a few columns is bound by memory at the sizes of large joins).
  // The values are those cached_cross() would compute one by one. Returns how many it solved.
  std::size_t prepare(const std::vector<Pairing>& pairings) const;
  // Whether `pairing`'s conditioned cross term is cached (or nothing is kept, where it needs none).
  bool prepared(const Pairing& pairing) const;

  // How many of `left` pairings one panel (keep_each_within(), prepare()) takes with `kept`
  // kept: as many as keep their condition_work() within `work_unit` units, at least
  // kMinPanelPairings (four still keep a step near a millisecond at the largest joins measured,
  // where one pairing alone exceeds a unit) and at most kMaxPanelPairings, and at most `left`.
  static Eigen::Index panel_pairings(std::int64_t kept, Eigen::Index left, std::int64_t work_unit);
  static constexpr Eigen::Index kMinPanelPairings = 4;
  static constexpr Eigen::Index kMaxPanelPairings = kDefaultPanelWidth / 2;

  int kept() const { return static_cast<int>(kept_.size()); }
  // D^2 of the kept pairings (chain rule).
  double joint_distance_sq() const;
  // The work of condition() with `kept` pairings kept, in units (resumable_work.hpp).
  static std::int64_t condition_work(std::int64_t kept);

 private:
  using CrossBlock = Eigen::Matrix<double, Eigen::Dynamic, 2>;
  // Writes C_Ka, the covariances of the kept pairings with `pairing`, into the 2|K| x 2 `cross`.
  void write_cross(const Pairing& pairing, CrossColumns cross) const;
  // nu_a|K and C_aa|K of `pairing`, leaving its w_a in cross_ for keep().
  void condition(const Pairing& pairing, Vec2& innovation, Mat2& covariance);
  // Adds the pairing last passed to condition() to K, given the factor L_a of its conditional
  // covariance and its conditional innovation whitened, L_a^-1 nu_a|K.
  void keep(const Pairing& pairing, const Eigen::LLT<Mat2>& factor, const Vec2& whitened);
  // Grows L's and L^-1 nu_K's storage to at least `rows` rows, keeping their contents.
  void reserve_factor(Eigen::Index rows);
  // Writes L^-1 C_Ka into `cross` (2|K| x 2).
  void solve_cross(const Pairing& pairing, CrossBlock& cross) const;
  const CrossBlock& cached_cross(const Pairing& pairing) const;

  const PairingModel& base_;
  Eigen::MatrixXd lower_;  // L, grown a block at a time; only its lower triangle is read
  Eigen::VectorXd whitened_;  // L^-1 nu_K
  CrossBlock cross_;  // condition()'s w_a, for keep()
  Eigen::MatrixXd panel_cross_;  // keep_each_within()'s w_a, a pair of columns per pairing,
  Eigen::MatrixXd panel_gram_;   // their w_a' w_b
  Eigen::VectorXd panel_shift_;  // and their w_a' L^-1 nu_K
  // keep_each_within()'s pairings given K and each other: the factor of those it took, their
  // whitened innovations, a pairing's cross terms with them, and their positions in the panel.
  Eigen::MatrixXd panel_lower_;
  Eigen::VectorXd panel_whitened_;
  CrossBlock panel_cross_taken_;
  std::vector<Eigen::Index> panel_taken_;
  std::vector<Pairing> kept_;
  mutable std::unordered_map<std::uint64_t, CrossBlock> cache_;
};

}  // namespace dcslam
