#pragma once
// Checkpoints of EkfSlam and DCSlam (docs/api.md, "Checkpoint and resume"): the settled state
// of a filter as a versioned byte string, from which a filter is rebuilt that goes on bitwise as
// the original would. What is saved: the options, the maps (means, covariances, ids, storage
// capacity, which fixes Eigen's blocking and so the rounding), the id maps, tracks, counters and
// statistics, the association's spatial hash; for D&C the stack of maps and the join tree. A
// join in progress is saved as its inputs and the work budgets it has been given, and redone on
// load (a join is a deterministic function of its inputs and budgets), so the join classes need
// no serialisation of their own. Random choices are seeded per join from SlamConfig::seed, so
// there is no generator state to save.
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>

#include "dcslam/joining/dc_slam.hpp"
#include "dcslam/estimation/ekf_slam.hpp"

namespace dcslam {

// Checkpoints from another version of this format are refused rather than misread.
constexpr std::uint32_t kCheckpointVersion = 24;

// InvalidArgument for a D&C filter with a join oracle (a research instrument) or a failed join.
// Threaded D&C: taken under the stack's lock; the join the worker is running is saved as not
// started (the worker redoes it after load).
std::string save_checkpoint(const EkfSlam& filter);
std::string save_checkpoint(const DCSlam& filter);

// InvalidArgument ("checkpoint: ...") for bytes that are not a checkpoint of that filter:
// truncated, corrupted (checksum), another format version or another filter's.
std::unique_ptr<EkfSlam> load_ekf_checkpoint(std::string_view bytes);
std::unique_ptr<DCSlam> load_dc_checkpoint(std::string_view bytes);

}  // namespace dcslam
