#pragma once
// Chunked JCBB: the EKF's order of decisions at a map join (docs/data_association.md, "The
// EKF's order at large joins"). The measurements are taken in their own order (a join's m2
// features in map order, about the order the robot first saw them), a chunk of chunk_size
// measurements at a time; each chunk is decided by a node-bounded JCBB whose innovations and
// covariances are conditioned on every pairing the chunks before it accepted
// (ConditionedPairingModel), and its candidates are first gated again, conditioned, at
// candidate_gate, features already paired left out. Near the junction of two maps the
// relative pose is loose and a chunk is a small constellation that JCBB decides exactly;
// further on it is pinned by everything paired before, and only the features' own
// uncertainty is left, as for an EKF that has just closed its loop.
//
// Cost: each candidate is gated once, conditioned on the k pairings kept so far, O(k^2); each
// chunk's JCBB is bounded by max_nodes; O(c k^2) for c candidates in all.
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <vector>

#include "dcslam/association/conditioned_model.hpp"
#include "dcslam/association/jcbb.hpp"
#include "dcslam/core/resumable_work.hpp"

namespace dcslam {

struct ChunkedJcbbOptions {
  int chunk_size = 32;  // measurements with a candidate per chunk
  double confidence = 0.99;  // of each chunk's joint test
  double candidate_gate = 0.0;  // conditional D^2 a candidate must pass to enter its chunk
  // Of each chunk's JCBB. 2,000 by measurement: long_revisits' recall is the same as at 20,000
  // (0.820 and 0.818 over 20 seeds) at a sixth less CPU in all (docs/data_association.md, "The
  // EKF's order at large joins").
  std::int64_t max_nodes = 2000;
  // Work (units, resumable_work.hpp) after which a step of a chunk's JCBB pauses its search:
  // what bounds the time of an amortized step, the search being sliced at node boundaries. A
  // quarter of a join's unit: the search's units (hashed covariance blocks, small triangular
  // solves) take 2-3 ns each on Victoria Park, four to five times a join's (BENCHMARKS.md).
  std::int64_t work_unit = work_units(kDefaultWorkUnit) / 4;
  // A hypothesis to beat: the search stops as soon as it can no longer pair more than this
  // (its pairings plus the measurements left with a candidate, checked between chunks), its
  // result then partial and flagged `abandoned`. A search that ends above it is not changed.
  // -1: none.
  int to_beat = -1;
};

struct ChunkedJcbbResult {
  std::vector<int> feature_of;  // per measurement: its feature, or kStar
  int pairings = 0;
  int chunks = 0;
  int bound_hits = 0;  // chunks whose JCBB stopped at max_nodes
  bool abandoned = false;  // stopped where it could no longer beat options.to_beat
};

// Resumable (ResumableWork): a step gates one measurement's candidates (solving those of the
// next few measurements with them, ConditionedPairingModel::prepare()), starts a chunk's JCBB
// (ranks its candidates), expands its search by options.work_unit, or keeps a panel of its
// pairings (ConditionedPairingModel::keep_each_within()); the steps depend on the sizes and
// the search alone, so the result is bitwise the same however the work is sliced.
// `candidates` (per measurement, features 0..n-1 with n = num_features) and `model` must
// outlive it.
class ChunkedJcbb : public ResumableWork<ChunkedJcbb> {
 public:
  ChunkedJcbb(const CandidateLists& candidates, const PairingModel& model, int num_features,
              const ChunkedJcbbOptions& options);
  ChunkedJcbb(const ChunkedJcbb&) = delete;
  ChunkedJcbb& operator=(const ChunkedJcbb&) = delete;

  std::int64_t step(std::int64_t budget);
  bool done() const { return stage_ == Stage::Done; }
  // An estimate: every candidate left gated, and as many pairings kept, against the overlap.
  std::int64_t remaining_work() const;
  // The estimate before the first step, for `candidates` candidates over `overlap` measurements.
  static std::int64_t work_estimate(std::int64_t candidates, std::int64_t overlap, int chunk_size);
  // Valid once done().
  const ChunkedJcbbResult& result() const { return result_; }

 private:
  enum class Stage { Gate, Start, Search, Keep, Done };
  std::int64_t gate_next();
  std::int64_t start_chunk();
  std::int64_t search_chunk();
  // Work of the current chunk's JCBB and of the covariance blocks it computed, so far.
  std::int64_t chunk_work() const { return jcbb_.work_done() + chunk_model_->work_done(); }
  std::int64_t keep_next();
  // After a chunk: on to the next, or done (at the end, or when to_beat is out of reach).
  void next_chunk();
  static std::int64_t work(std::int64_t candidates, std::int64_t to_keep, std::int64_t overlap, int chunk_size);
  // The chunk's candidate pairings conditioned on the kept ones, with their measurements
  // numbered 0..size-1 for its JCBB. Each covariance block between two of them is computed
  // once, when the search first asks for it (O(|K|)), where the search would compute it again
  // at every node that reaches it; only the blocks asked for are held, at most the nodes times
  // the chunk size, where all of them would be O(s^2) for s candidates (thousands at a loop
  // closed at large uncertainty).
  class ChunkModel : public PairingModel {
   public:
    ChunkModel(const ConditionedPairingModel& conditioned, const std::vector<int>& measurements,
               const CandidateLists& candidates);
    Vec2 innovation(const Pairing& pairing) const override;
    Mat2 covariance(const Pairing& a, const Pairing& b) const override;
    // Work of the blocks computed so far, in units: each a block of the conditioned model.
    std::int64_t work_done() const { return work_; }

   private:
    std::size_t slot(const Pairing& pairing) const;
    const PairingModel& conditioned_;
    const CandidateLists& candidates_;
    std::vector<Pairing> pairings_;  // per slot, with the measurement as the caller's
    std::vector<std::size_t> first_slot_;  // per measurement of the chunk
    std::vector<Vec2> innovations_;  // per slot
    mutable std::unordered_map<std::uint64_t, Mat2> blocks_;  // (later slot, earlier slot)
    std::int64_t block_work_;  // of one block
    mutable std::int64_t work_ = 0;
  };

  const CandidateLists& candidates_;
  ChunkedJcbbOptions options_;
  ConditionedPairingModel conditioned_;
  Jcbb jcbb_;
  Stage stage_ = Stage::Gate;
  ChunkedJcbbResult result_;
  std::vector<char> feature_used_;
  std::size_t next_ = 0;  // next measurement to gate
  std::int64_t candidates_left_ = 0;  // in the lists of measurements not yet gated
  int overlap_ = 0;  // measurements with a candidate
  int overlap_left_ = 0;  // of them, not yet gated
  std::vector<int> chunk_;  // its measurements
  CandidateLists chunk_candidates_;
  std::optional<ChunkModel> chunk_model_;  // while its JCBB searches
  std::vector<Pairing> accepted_;  // the chunk's pairings (global), to keep
  std::size_t next_kept_ = 0;
  std::vector<Pairing> panel_;  // the pairings a step solves or keeps at once
  std::vector<double> panel_gates_;
  std::vector<char> panel_kept_;
};

}  // namespace dcslam
