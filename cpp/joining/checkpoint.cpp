#include "dcslam/joining/checkpoint.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <type_traits>
#include <utility>
#include <vector>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

constexpr char kMagic[8] = {'D', 'C', 'S', 'L', 'A', 'M', 'C', 'K'};
constexpr std::uint32_t kByteOrderMark = 0x01020304;
constexpr std::uint8_t kEkfKind = 'E', kDcKind = 'D';
// magic, version, byte order, kind, payload size, checksum.
constexpr std::size_t kHeaderBytes = 8 + 4 + 4 + 1 + 8 + 8;

// FNV-1a: not a cryptographic hash, a check that the bytes are those that were written.
std::uint64_t checksum(std::string_view bytes) {
  std::uint64_t hash = 0xcbf29ce484222325ULL;
  for (const char c : bytes) {
    hash ^= static_cast<unsigned char>(c);
    hash *= 0x100000001b3ULL;
  }
  return hash;
}

class Writer {
 public:
  template <typename T>
  void pod(T value) {
    static_assert(std::is_trivially_copyable_v<T>);
    bytes_.append(reinterpret_cast<const char*>(&value), sizeof(T));
  }
  void count(std::size_t n) { pod<std::uint64_t>(n); }
  void doubles(const double* values, std::size_t n) {
    bytes_.append(reinterpret_cast<const char*>(values), n * sizeof(double));
  }
  void ids(const std::vector<std::int64_t>& values) {
    count(values.size());
    bytes_.append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(std::int64_t));
  }
  void text(const std::string& value) {
    count(value.size());
    bytes_.append(value);
  }
  std::string finish(std::uint8_t kind) const {
    std::string out(kMagic, sizeof(kMagic));
    const auto append = [&out](auto value) { out.append(reinterpret_cast<const char*>(&value), sizeof(value)); };
    append(kCheckpointVersion);
    append(kByteOrderMark);
    append(kind);
    append(static_cast<std::uint64_t>(bytes_.size()));
    append(checksum(bytes_));
    return out + bytes_;
  }

 private:
  std::string bytes_;
};

class Reader {
 public:
  // Checks the header and the checksum; reads the payload after it.
  Reader(std::string_view bytes, std::uint8_t expected_kind, const char* filter) {
    if (bytes.size() < kHeaderBytes || std::memcmp(bytes.data(), kMagic, sizeof(kMagic)) != 0) {
      fail("not a dcslam checkpoint (" + std::to_string(bytes.size()) + " bytes without its header)");
    }
    data_ = bytes.substr(sizeof(kMagic));
    const auto version = pod<std::uint32_t>();
    if (version != kCheckpointVersion) {
      fail("format version " + std::to_string(version) + ", this dcslam reads version " +
           std::to_string(kCheckpointVersion));
    }
    if (pod<std::uint32_t>() != kByteOrderMark) fail("written on a machine of another byte order");
    const auto kind = pod<std::uint8_t>();
    if (kind != expected_kind) {
      fail(std::string("this is a checkpoint of ") + (kind == kEkfKind ? "an EkfSlam" : kind == kDcKind ? "a DCSlam" : "no known filter") +
           ", not of " + filter);
    }
    const auto size = pod<std::uint64_t>();
    const auto sum = pod<std::uint64_t>();
    if (size != data_.size()) {
      fail("truncated or extended: " + std::to_string(data_.size()) + " bytes of payload, expected " +
           std::to_string(size));
    }
    if (checksum(data_) != sum) fail("corrupted (checksum mismatch)");
  }

  template <typename T>
  T pod() {
    static_assert(std::is_trivially_copyable_v<T>);
    need(sizeof(T));
    T value;
    std::memcpy(&value, data_.data(), sizeof(T));
    data_.remove_prefix(sizeof(T));
    return value;
  }
  bool flag() {
    const auto value = pod<std::uint8_t>();
    if (value > 1) fail("a flag of value " + std::to_string(value));
    return value == 1;
  }
  // A count of elements of `element_bytes` each that the bytes left can hold: no allocation is
  // ever sized by a corrupted count.
  std::size_t count(std::size_t element_bytes) {
    const auto n = pod<std::uint64_t>();
    if (n > data_.size() / std::max<std::size_t>(1, element_bytes)) {
      fail("a count of " + std::to_string(n) + " beyond the bytes left");
    }
    return static_cast<std::size_t>(n);
  }
  void doubles(double* out, std::size_t n) {
    need(n * sizeof(double));
    std::memcpy(out, data_.data(), n * sizeof(double));
    data_.remove_prefix(n * sizeof(double));
  }
  std::vector<std::int64_t> ids() {
    std::vector<std::int64_t> values(count(sizeof(std::int64_t)));
    std::memcpy(values.data(), data_.data(), values.size() * sizeof(std::int64_t));
    data_.remove_prefix(values.size() * sizeof(std::int64_t));
    return values;
  }
  std::string text() {
    const std::size_t n = count(1);
    std::string value(data_.substr(0, n));
    data_.remove_prefix(n);
    return value;
  }
  void finish() const {
    if (!data_.empty()) fail(std::to_string(data_.size()) + " bytes left over after the filter's state");
  }
  [[noreturn]] static void fail(const std::string& what) { throw InvalidArgument("checkpoint: " + what); }
  static void require(bool condition, const char* what) {
    if (!condition) fail(std::string("inconsistent state: ") + what);
  }

 private:
  void need(std::size_t n) const {
    if (n > data_.size()) fail("truncated (" + std::to_string(n) + " more bytes needed, " + std::to_string(data_.size()) + " left)");
  }
  std::string_view data_;
};

// ---- plain values -------------------------------------------------------------------------

// A field added to SlamConfig must be added here too (and kCheckpointVersion raised): the size
// check below fails the build until it is.
static_assert(sizeof(SlamConfig) == 256, "SlamConfig changed: update save_config/load_config");

// A flag and the value (0 when unset), read back as set or unset whatever the field's default.
template <typename T>
void optional_value(Writer& out, const std::optional<T>& value) {
  out.pod<std::uint8_t>(value.has_value());
  out.pod(value.value_or(T{}));
}

template <typename T>
std::optional<T> optional_value(Reader& in) {
  const bool has_value = in.flag();
  const auto value = in.pod<T>();
  return has_value ? std::optional<T>(value) : std::nullopt;
}

void save_config(Writer& out, const SlamConfig& c) {
  out.pod<std::uint8_t>(static_cast<std::uint8_t>(c.observation));
  out.doubles(c.sensor_offset.data(), 3);
  out.pod<std::uint8_t>(static_cast<std::uint8_t>(c.association));
  out.pod(c.gate_confidence);
  out.pod(c.unexplained_density);
  out.pod(c.new_feature_margin);
  out.pod<std::uint8_t>(c.new_feature_beside_tentative);
  optional_value(out, c.confirmed_first_confidence);
  out.pod(c.jcbb_max_nodes);
  out.pod(c.min_sightings);
  out.pod(c.tentative_window);
  out.pod(c.merge_radius);
  optional_value(out, c.final_merge_confidence);
  out.pod(c.final_merge_shared_scans);
  out.pod(c.join_merge_max_leaves);
  out.pod(c.weak_join_pairings);
  out.pod(c.local_map_features);
  out.pod<std::uint8_t>(static_cast<std::uint8_t>(c.join_association));
  out.pod(c.rjc_b);
  out.pod(c.rjc_p_good);
  out.pod(c.rjc_p_fail);
  out.pod<std::uint8_t>(c.rjc_exchange_crossed);
  out.pod(c.join_iterations);
  out.pod(c.join_feature_sigma);
  out.pod(c.large_overlap_confidence);
  out.pod(c.chunked_jcbb_min_overlap);
  optional_value(out, c.join_rival_margin);
  out.pod(c.tree_relinearisation);
  out.pod(c.tree_relinearisation_tolerance);
  out.pod(c.seed);
  out.pod<std::uint8_t>(c.amortize);
  out.pod<std::uint8_t>(c.threaded_joins);
  out.pod(c.estimate_threads);
  out.pod<std::uint8_t>(c.keep_local_map_poses);
  optional_value(out, c.online_localisation_sigma);
}

template <typename Enum>
Enum enum_value(Reader& in, int count) {
  const auto value = in.pod<std::uint8_t>();
  if (value >= count) Reader::fail("an option value " + std::to_string(value) + " out of range");
  return static_cast<Enum>(value);
}

SlamConfig load_config(Reader& in) {
  SlamConfig c;
  c.observation = enum_value<ObservationModel>(in, 2);
  in.doubles(c.sensor_offset.data(), 3);
  c.association = enum_value<Association>(in, 3);
  c.gate_confidence = in.pod<double>();
  c.unexplained_density = in.pod<double>();
  c.new_feature_margin = in.pod<double>();
  c.new_feature_beside_tentative = in.flag();
  c.confirmed_first_confidence = optional_value<double>(in);
  c.jcbb_max_nodes = in.pod<std::int64_t>();
  c.min_sightings = in.pod<int>();
  c.tentative_window = in.pod<int>();
  c.merge_radius = in.pod<double>();
  c.final_merge_confidence = optional_value<double>(in);
  c.final_merge_shared_scans = in.pod<int>();
  c.join_merge_max_leaves = in.pod<int>();
  c.weak_join_pairings = in.pod<int>();
  c.local_map_features = in.pod<int>();
  c.join_association = enum_value<JoinAssociation>(in, 3);
  c.rjc_b = in.pod<int>();
  c.rjc_p_good = in.pod<double>();
  c.rjc_p_fail = in.pod<double>();
  c.rjc_exchange_crossed = in.flag();
  c.join_iterations = in.pod<int>();
  c.join_feature_sigma = in.pod<double>();
  c.large_overlap_confidence = in.pod<double>();
  c.chunked_jcbb_min_overlap = in.pod<int>();
  c.join_rival_margin = optional_value<int>(in);
  c.tree_relinearisation = in.pod<int>();
  c.tree_relinearisation_tolerance = in.pod<double>();
  c.seed = in.pod<std::uint64_t>();
  c.amortize = in.flag();
  c.threaded_joins = in.flag();
  c.estimate_threads = in.pod<int>();
  c.keep_local_map_poses = in.flag();
  c.online_localisation_sigma = optional_value<double>(in);
  c.validate();  // InvalidArgument naming the field
  return c;
}

// The storage capacity is saved too: it sets the stride of P, and with it the alignment Eigen's
// vectorised loops start from, hence the rounding of everything computed on the map.
void save_map(Writer& out, const GaussianMap& map) {
  out.pod<std::int64_t>(map.capacity());
  out.pod<std::int64_t>(map.dim());
  out.ids(map.ids());
  out.ids(map.pose_ids());
  const Eigen::VectorXd x = map.x();
  out.doubles(x.data(), static_cast<std::size_t>(x.size()));
  const Eigen::MatrixXd P = map.P();
  out.doubles(P.data(), static_cast<std::size_t>(P.size()));
}

// A local map's log (leaf_relinearisation.hpp): steps, then measurements.
void save_log(Writer& out, const LeafLog& log) {
  out.count(log.u.size());
  for (std::size_t t = 0; t < log.u.size(); ++t) {
    out.doubles(log.u[t].data(), 3);
    out.doubles(log.Q[t].data(), 9);
  }
  out.count(log.measurements.size());
  for (const LeafMeasurement& m : log.measurements) {
    out.doubles(m.z.data(), 2);
    out.doubles(m.R.data(), 4);
    out.pod(m.feature);
    out.pod(m.pose);
  }
}

LeafLog load_log(Reader& in) {
  LeafLog log;
  log.u.resize(in.count(12 * sizeof(double)));
  log.Q.resize(log.u.size());
  for (std::size_t t = 0; t < log.u.size(); ++t) {
    in.doubles(log.u[t].data(), 3);
    in.doubles(log.Q[t].data(), 9);
    Reader::require(log.u[t].allFinite() && log.Q[t].allFinite(), "a logged motion that is not finite");
  }
  log.measurements.resize(in.count(6 * sizeof(double) + 16));
  std::int64_t previous_pose = 0;
  for (LeafMeasurement& m : log.measurements) {
    in.doubles(m.z.data(), 2);
    in.doubles(m.R.data(), 4);
    m.feature = in.pod<std::int64_t>();
    m.pose = in.pod<std::int64_t>();
    Reader::require(m.z.allFinite() && m.R.allFinite(), "a logged measurement that is not finite");
    Reader::require(m.pose >= previous_pose && m.pose <= static_cast<std::int64_t>(log.u.size()),
                    "a logged measurement out of step order");
    previous_pose = m.pose;
  }
  return log;
}

GaussianMap load_map(Reader& in) {
  const auto capacity = in.pod<std::int64_t>();
  const auto dim = in.pod<std::int64_t>();
  std::vector<std::int64_t> ids = in.ids();
  std::vector<std::int64_t> pose_ids = in.ids();
  const auto n = static_cast<std::int64_t>(ids.size());
  const auto m = static_cast<std::int64_t>(pose_ids.size());
  Reader::require(dim == GaussianMap::kRobotDim + GaussianMap::kFeatureDim * n + GaussianMap::kPoseDim * m,
                  "a map's dimension does not match its ids");
  Reader::require(capacity >= dim, "a map's capacity is below its dimension");
  // The bytes must be there before the storage is sized.
  Reader::require(static_cast<double>(dim) * static_cast<double>(dim) < 1e12, "a map's dimension is absurd");
  GaussianMap map;
  if (capacity == dim) {
    map = GaussianMap::uninitialized(n, m);
  } else {
    Reader::require(m == 0, "a growing map with past poses");
    map.reserve(capacity);
    map.resize(dim);
  }
  Reader::require(map.capacity() == capacity, "a map's capacity that its growth never gives");
  map.ids() = std::move(ids);
  map.pose_ids() = std::move(pose_ids);
  Eigen::VectorXd x(dim);
  in.doubles(x.data(), static_cast<std::size_t>(dim));
  Eigen::MatrixXd P(dim, dim);
  in.doubles(P.data(), static_cast<std::size_t>(dim * dim));
  map.x() = x;
  map.P() = P;
  return map;
}

void save_stats(Writer& out, const RunStats& stats) {
  out.count(stats.steps.size());
  for (const StepStats& s : stats.steps) {
    out.pod(s.seconds);
    out.pod(s.num_features);
    out.pod(s.measurements);
    out.pod(s.paired);
    out.pod(s.new_features);
    out.pod(s.rejected);
    out.pod(s.association_seconds);
  }
  out.count(stats.counters.size());
  for (const auto& [name, value] : stats.counters) {
    out.text(name);
    out.pod(value);
  }
}

RunStats load_stats(Reader& in) {
  RunStats stats;
  stats.steps.resize(in.count(8 + 8 + 4 * 4 + 8));
  for (StepStats& s : stats.steps) {
    s.seconds = in.pod<double>();
    s.num_features = in.pod<std::int64_t>();
    s.measurements = in.pod<int>();
    s.paired = in.pod<int>();
    s.new_features = in.pod<int>();
    s.rejected = in.pod<int>();
    s.association_seconds = in.pod<double>();
  }
  const std::size_t counters = in.count(16);
  for (std::size_t k = 0; k < counters; ++k) {
    std::string name = in.text();
    stats.counters[name] = in.pod<double>();
  }
  return stats;
}

// Unordered containers are written in key order: the same state always gives the same bytes.
void save_aliases(Writer& out, const IdAliases& aliases) {
  std::vector<std::pair<std::int64_t, std::int64_t>> sorted(aliases.begin(), aliases.end());
  std::sort(sorted.begin(), sorted.end());
  out.count(sorted.size());
  for (const auto& [from, to] : sorted) {
    out.pod(from);
    out.pod(to);
  }
}

IdAliases load_aliases(Reader& in) {
  IdAliases aliases;
  const std::size_t n = in.count(16);
  for (std::size_t k = 0; k < n; ++k) {
    const auto from = in.pod<std::int64_t>();
    aliases[from] = in.pod<std::int64_t>();
  }
  return aliases;
}

void save_pairs(Writer& out, const std::vector<std::pair<std::int64_t, std::int64_t>>& pairs) {
  out.count(pairs.size());
  for (const auto& [a, b] : pairs) {
    out.pod(a);
    out.pod(b);
  }
}

std::vector<std::pair<std::int64_t, std::int64_t>> load_pairs(Reader& in) {
  std::vector<std::pair<std::int64_t, std::int64_t>> pairs(in.count(16));
  for (auto& [a, b] : pairs) {
    a = in.pod<std::int64_t>();
    b = in.pod<std::int64_t>();
  }
  return pairs;
}

void save_flags(Writer& out, const std::vector<char>& flags) {
  out.count(flags.size());
  for (const char f : flags) out.pod<std::uint8_t>(f ? 1 : 0);
}

std::vector<char> load_flags(Reader& in) {
  std::vector<char> flags(in.count(1));
  for (char& f : flags) f = in.flag() ? 1 : 0;
  return flags;
}

void save_pairing(Writer& out, const JoinPairingRecord& r) {
  out.ids(r.first_ids);
  out.ids(r.second_ids);
  save_pairs(out, r.pairs);
  save_pairs(out, r.truth_pairs);
  out.count(r.truth_distance_sq.size());
  out.doubles(r.truth_distance_sq.data(), r.truth_distance_sq.size());
  save_flags(out, r.truth_candidate);
  save_flags(out, r.truth_consistent);
  save_pairs(out, r.own_pairs);
  save_pairs(out, r.merged);
  save_pairs(out, r.disputed);
}

JoinPairingRecord load_pairing(Reader& in) {
  JoinPairingRecord r;
  r.first_ids = in.ids();
  r.second_ids = in.ids();
  r.pairs = load_pairs(in);
  r.truth_pairs = load_pairs(in);
  r.truth_distance_sq.resize(in.count(8));
  in.doubles(r.truth_distance_sq.data(), r.truth_distance_sq.size());
  r.truth_candidate = load_flags(in);
  r.truth_consistent = load_flags(in);
  r.own_pairs = load_pairs(in);
  r.merged = load_pairs(in);
  r.disputed = load_pairs(in);
  return r;
}

void save_join_ids(Writer& out, const JoinIds& ids) {
  save_pairs(out, ids.merged);
  out.ids(ids.dropped);
}

JoinIds load_join_ids(Reader& in) {
  JoinIds ids;
  ids.merged = load_pairs(in);
  ids.dropped = in.ids();
  return ids;
}

void save_event(Writer& out, const JoinEvent& e) {
  out.pod(e.index);
  out.pod(e.leaves);
  out.pod(e.step_created);
  out.pod(e.step_finished);
  const JoinReport& r = e.report;
  out.pod<std::int64_t>(r.features_first);
  out.pod<std::int64_t>(r.features_second);
  out.pod<std::int64_t>(r.features_joined);
  out.pod(r.overlap);
  out.pod(r.pairings);
  out.pod(r.tries);
  out.pod<std::uint8_t>(r.chunked);
  out.pod<std::uint8_t>(r.widened);
  out.pod(r.dropped_tentative);
  out.pod(r.deferred_pairings);
  out.pod(r.alternatives_taken);
  out.pod(r.iterations);
  out.pod(r.constraint_distance_sq);
  out.pod(r.seconds_association);
  out.pod(r.seconds_total);
  out.pod(r.work_units);
  save_pairing(out, e.pairing);
}

JoinEvent load_event(Reader& in) {
  JoinEvent e;
  e.index = in.pod<int>();
  e.leaves = in.pod<int>();
  e.step_created = in.pod<std::int64_t>();
  e.step_finished = in.pod<std::int64_t>();
  JoinReport& r = e.report;
  r.features_first = in.pod<std::int64_t>();
  r.features_second = in.pod<std::int64_t>();
  r.features_joined = in.pod<std::int64_t>();
  r.overlap = in.pod<int>();
  r.pairings = in.pod<int>();
  r.tries = in.pod<int>();
  r.chunked = in.flag();
  r.widened = in.flag();
  r.dropped_tentative = in.pod<int>();
  r.deferred_pairings = in.pod<int>();
  r.alternatives_taken = in.pod<int>();
  r.iterations = in.pod<int>();
  r.constraint_distance_sq = in.pod<double>();
  r.seconds_association = in.pod<double>();
  r.seconds_total = in.pod<double>();
  r.work_units = in.pod<std::int64_t>();
  e.pairing = load_pairing(in);
  return e;
}

}  // namespace

// Reaches the filters' private state (a friend of EkfSlam and DCSlam).
struct CheckpointAccess {
  static void save(Writer& out, const EkfSlam& f) {
    save_config(out, f.config_);
    save_map(out, f.map_);
    out.pod(f.next_fresh_id_);
    out.pod(f.step_);
    out.pod(f.keep_until_step_);
    save_stats(out, f.stats_);
    out.count(f.tracks_.size());
    for (const EkfSlam::Track& t : f.tracks_) {
      out.pod(t.sightings);
      out.pod(t.first_seen_step);
      out.pod(t.last_seen_step);
      out.ids(t.seen_with);
    }
    std::vector<std::int64_t> removed(f.removed_ids_.begin(), f.removed_ids_.end());
    std::sort(removed.begin(), removed.end());
    out.ids(removed);
    save_aliases(out, f.merged_into_);
    // The update's workspaces only grow, and their strides set the rounding of the blocks
    // computed in them: they are restored at the size they had.
    out.pod<std::int64_t>(f.PHt_.rows());
    out.pod<std::int64_t>(f.PHt_.cols());
    out.pod<std::int64_t>(f.S_.rows());
    out.pod<std::uint8_t>(f.association_.has_value());
    if (f.association_) {
      const EkfAssociation::SavedState state = f.association_->saved_state();
      out.pod(state.cell_size);
      out.pod(state.sigma_feature);
      out.count(state.hashed_positions.size());
      for (const Vec2& p : state.hashed_positions) out.doubles(p.data(), 2);
    }
  }

  static std::unique_ptr<EkfSlam> load_ekf(Reader& in) {
    auto f = std::make_unique<EkfSlam>(load_config(in));
    f->map_ = load_map(in);
    Reader::require(f->map_.num_poses() == 0, "an EKF map with past poses");
    f->next_fresh_id_ = in.pod<std::int64_t>();
    f->step_ = in.pod<std::int64_t>();
    f->keep_until_step_ = in.pod<std::int64_t>();
    f->stats_ = load_stats(in);
    f->tracks_.resize(in.count(4 + 8 + 8 + 8));
    for (EkfSlam::Track& t : f->tracks_) {
      t.sightings = in.pod<int>();
      t.first_seen_step = in.pod<std::int64_t>();
      t.last_seen_step = in.pod<std::int64_t>();
      t.seen_with = in.ids();
    }
    const auto n = static_cast<std::size_t>(f->map_.num_features());
    Reader::require(f->tracks_.size() == n, "tracks do not match the features");
    for (const std::int64_t id : in.ids()) f->removed_ids_.insert(id);
    f->merged_into_ = load_aliases(in);
    for (std::size_t k = 0; k < n; ++k) {
      Reader::require(f->index_of_id_.emplace(f->map_.ids()[k], static_cast<Eigen::Index>(k)).second,
                      "a feature id twice in one map");
    }
    const auto workspace_rows = in.pod<std::int64_t>();
    const auto workspace_cols = in.pod<std::int64_t>();
    const auto innovation_rows = in.pod<std::int64_t>();
    Reader::require(workspace_rows >= 0 && workspace_rows < (1 << 24) && workspace_cols >= 0 &&
                        workspace_cols < (1 << 20) && innovation_rows == workspace_cols &&
                        static_cast<double>(workspace_rows) * static_cast<double>(workspace_cols) < 1e10,
                    "the update's workspace sizes");
    f->PHt_.resize(workspace_rows, workspace_cols);
    f->S_.resize(innovation_rows, innovation_rows);
    f->innovation_.resize(innovation_rows);
    const bool has_association = in.flag();
    Reader::require(has_association == f->association_.has_value(), "association state and mode disagree");
    if (has_association) {
      EkfAssociation::SavedState state;
      state.cell_size = in.pod<double>();
      state.sigma_feature = in.pod<double>();
      state.hashed_positions.resize(in.count(16));
      Reader::require(state.hashed_positions.size() == n, "hashed positions do not match the features");
      Reader::require(std::isfinite(state.cell_size) && state.cell_size > 0, "the hash's cell size");
      for (Vec2& p : state.hashed_positions) {
        in.doubles(p.data(), 2);
        Reader::require(p.allFinite(), "a hashed position that is not finite");
      }
      f->association_->restore(state);
    }
    return f;
  }

  static void save_tentative(Writer& out, const std::vector<TentativeFeature>& tentative) {
    out.count(tentative.size());
    for (const TentativeFeature& t : tentative) {
      out.pod(t.id);
      out.pod(t.leaf);
      out.pod<std::uint8_t>(t.needs_previous);
      out.pod<std::uint8_t>(t.needs_next);
    }
  }

  static std::vector<TentativeFeature> load_tentative(Reader& in) {
    std::vector<TentativeFeature> tentative(in.count(8 + 8 + 2));
    for (TentativeFeature& t : tentative) {
      t.id = in.pod<std::int64_t>();
      t.leaf = in.pod<std::int64_t>();
      t.needs_previous = in.flag();
      t.needs_next = in.flag();
    }
    return tentative;
  }

  // The kept local maps and the tree's shape (tree_relinearisation > 0), and the last
  // estimate's pass count (a counter of stats()).
  static void save_tree(Writer& out, const DCSlam& f) {
    out.count(static_cast<std::size_t>(f.tree_.num_leaves()));
    for (std::int64_t k = 0; k < f.tree_.num_leaves(); ++k) {
      const TreeLeaf& leaf = f.tree_.leaf(k);
      save_map(out, *leaf.map);
      save_tentative(out, leaf.tentative);
      out.pod(leaf.robot_id);
      save_log(out, *leaf.log);
    }
    out.count(f.tree_.joins().size());
    for (const auto& [node, left_leaves] : f.tree_.joins()) {
      out.pod(node.first);
      out.pod(node.second);
      out.pod(left_leaves);
    }
    save_log(out, f.open_log_);
    out.pod(f.relinearisation_.passes);
    out.pod(f.relinearisation_.last_step);
    out.pod(f.relinearisation_.first_objective);
    out.pod(f.relinearisation_.objective);
    out.pod(f.relinearisation_.predicted_objective);
    out.pod(f.relinearisation_.halvings);
  }

  static void load_tree(Reader& in, DCSlam& f) {
    const std::size_t leaves = in.count(8);
    for (std::size_t k = 0; k < leaves; ++k) {
      TreeLeaf leaf;
      leaf.map = std::make_shared<const GaussianMap>(load_map(in));
      leaf.tentative = load_tentative(in);
      leaf.robot_id = in.pod<std::int64_t>();
      LeafLog log = load_log(in);
      for (const LeafMeasurement& m : log.measurements) {
        Reader::require(m.feature >= 0 && m.feature < leaf.map->num_features(),
                        "a kept local map's measurement of no feature of it");
      }
      leaf.log = std::make_shared<const LeafLog>(std::move(log));
      f.tree_.add_leaf(std::move(leaf));
    }
    const std::size_t joins = in.count(24);
    for (std::size_t k = 0; k < joins; ++k) {
      const auto first_leaf = in.pod<std::int64_t>();
      const auto node_leaves = in.pod<std::int64_t>();
      const auto left_leaves = in.pod<std::int64_t>();
      Reader::require(first_leaf >= 0 && left_leaves >= 1 && left_leaves < node_leaves &&
                          first_leaf + node_leaves <= static_cast<std::int64_t>(leaves),
                      "a join of the kept tree outside its local maps");
      f.tree_.add_join(TreeSpan{first_leaf, left_leaves}, TreeSpan{first_leaf + left_leaves, node_leaves - left_leaves});
    }
    f.open_log_ = load_log(in);
    f.relinearisation_.passes = in.pod<int>();
    f.relinearisation_.last_step = in.pod<double>();
    f.relinearisation_.first_objective = in.pod<double>();
    f.relinearisation_.objective = in.pod<double>();
    f.relinearisation_.predicted_objective = in.pod<double>();
    f.relinearisation_.halvings = in.pod<int>();
  }

  static void save_localisation(Writer& out, const DCSlam::PendingLocalisation& pending) {
    const LocalisationInputs& inputs = pending.inputs;
    save_map(out, *inputs.oldest);
    out.count(inputs.between.size());
    for (const PoseLink& link : inputs.between) {
      out.doubles(link.mean.data(), 3);
      out.doubles(link.covariance.data(), 9);
    }
    save_map(out, *inputs.newest);
    out.ids(std::vector<std::int64_t>(inputs.left_out.begin(), inputs.left_out.end()));
    out.pod(inputs.options.rjc.seed);
    out.pod(pending.deadline_step);
    out.ids(pending.budgets);
  }

  static DCSlam::PendingLocalisation load_localisation(Reader& in, const DCSlam& f) {
    DCSlam::PendingLocalisation pending;
    LocalisationInputs& inputs = pending.inputs;
    inputs.oldest = std::make_shared<const GaussianMap>(load_map(in));
    inputs.between.resize(in.count(96));
    for (PoseLink& link : inputs.between) {
      for (Eigen::Index k = 0; k < 3; ++k) link.mean(k) = in.pod<double>();
      for (Eigen::Index k = 0; k < 9; ++k) link.covariance.data()[k] = in.pod<double>();
    }
    inputs.newest = std::make_shared<const GaussianMap>(load_map(in));
    for (const std::int64_t index : in.ids()) {
      Reader::require(index >= 0 && index < inputs.newest->num_features(), "a localisation's left-out feature");
      inputs.left_out.push_back(static_cast<Eigen::Index>(index));
    }
    inputs.max_sigma = f.config_.online_localisation_sigma.value_or(0.0);
    inputs.options = f.localisation_options(in.pod<std::uint64_t>());
    pending.deadline_step = in.pod<std::int64_t>();
    pending.budgets = in.ids();
    for (const std::int64_t budget : pending.budgets) Reader::require(budget > 0, "a localisation's budget");
    return pending;
  }

  static void save_node(Writer& out, const DCSlam::Node& node, bool keep_budgets) {
    out.pod(node.leaves);
    out.pod(node.first_leaf);
    out.pod(node.expected_features);
    out.pod(node.expected_poses);
    out.pod(node.robot_id);
    out.pod<std::uint8_t>(node.map != nullptr);
    if (node.map) {
      save_map(out, *node.map);
      save_tentative(out, node.tentative);
      out.pod<std::uint8_t>(node.alternative != nullptr);
      if (node.alternative) {
        save_join_ids(out, node.alternative->made_ids);
        out.pod(node.alternative->join_index);
        out.pod(static_cast<std::uint32_t>(node.alternative->versions.size()));
        for (const JoinAlternative::Version& version : node.alternative->versions) {
          save_map(out, *version.map);
          save_tentative(out, version.tentative);
          save_join_ids(out, version.ids);
        }
      }
      return;
    }
    const DCSlam::JoinTask& task = *node.task;
    out.pod(task.index);
    out.pod(task.deadline_step);
    out.ids(keep_budgets ? task.budgets : std::vector<std::int64_t>{});
    save_node(out, *task.left, keep_budgets);
    save_node(out, *task.right, keep_budgets);
  }

  static std::shared_ptr<DCSlam::Node> load_node(Reader& in, std::vector<std::shared_ptr<DCSlam::JoinTask>>& tasks,
                                                 int depth) {
    Reader::require(depth < 64, "a join tree deeper than 64");
    auto node = std::make_shared<DCSlam::Node>();
    node->leaves = in.pod<int>();
    node->first_leaf = in.pod<std::int64_t>();
    node->expected_features = in.pod<std::int64_t>();
    node->expected_poses = in.pod<std::int64_t>();
    node->robot_id = in.pod<std::int64_t>();
    if (in.flag()) {
      node->map = std::make_shared<const GaussianMap>(load_map(in));
      node->tentative = load_tentative(in);
      if (in.flag()) {
        auto alternative = std::make_shared<JoinAlternative>();
        alternative->made_ids = load_join_ids(in);
        alternative->join_index = in.pod<int>();
        Reader::require(alternative->join_index >= 0 && static_cast<std::size_t>(alternative->join_index) < tasks.size(),
                        "the index of a join left to the next join's decision beyond the joins made");
        const auto versions = in.pod<std::uint32_t>();
        Reader::require(versions >= 1 && versions <= 2, "a join left to the next join's decision with 1 or 2 other versions");
        for (std::uint32_t k = 0; k < versions; ++k) {
          JoinAlternative::Version version;
          version.map = std::make_shared<const GaussianMap>(load_map(in));
          version.tentative = load_tentative(in);
          version.ids = load_join_ids(in);
          alternative->versions.push_back(std::move(version));
        }
        node->alternative = std::move(alternative);
      }
      return node;
    }
    auto task = std::make_shared<DCSlam::JoinTask>();
    task->index = in.pod<int>();
    task->deadline_step = in.pod<std::int64_t>();
    task->budgets = in.ids();
    task->left = load_node(in, tasks, depth + 1);
    task->right = load_node(in, tasks, depth + 1);
    task->result = node;
    Reader::require(task->index >= 0 && static_cast<std::size_t>(task->index) < tasks.size() && !tasks[task->index],
                    "a join index out of range or twice");
    Reader::require(task->budgets.empty() || (task->left->map && task->right->map), "a started join without its inputs");
    tasks[static_cast<std::size_t>(task->index)] = task;
    node->task = std::move(task);
    return node;
  }

  static void save(Writer& out, const DCSlam& f) {
    std::lock_guard<std::mutex> lock(f.mutex_);
    if (f.join_oracle_) throw InvalidArgument("checkpoint: a DCSlam with a join oracle (a research instrument) is not saved");
    if (!f.join_failure_.empty()) {
      throw InvalidArgument("checkpoint: " + f.join_failure_ +
                            "; not saved: the next call to the filter reports it");
    }
    save_config(out, f.config_);
    save(out, *f.local_);
    out.pod(f.local_map_steps_);
    out.pod<std::int64_t>(f.steps_);
    out.pod(f.predictions_);
    out.pod(f.closed_local_maps_);
    out.pod(f.steps_in_closed_maps_);
    out.pod<std::uint8_t>(f.localised_base_.has_value());
    const Vec3 localised_base = f.localised_base_.value_or(Vec3::Zero());
    out.doubles(localised_base.data(), 3);
    out.pod(f.online_localisations_);
    const std::optional<DCSlam::PendingLocalisation> localisation = f.pending_localisation();
    out.pod<std::uint8_t>(localisation.has_value());
    if (localisation) save_localisation(out, *localisation);
    out.pod(f.joins_created_);
    // Threaded: the worker runs a join in one go, so a started one is redone from its inputs.
    const bool keep_budgets = !f.config_.threaded_joins;
    out.count(f.stack_.size());
    for (const auto& node : f.stack_) save_node(out, *node, keep_budgets);
    out.count(f.queue_.size());
    for (const auto& task : f.queue_) out.pod(task->index);
    out.count(f.events_.size());
    for (const JoinEvent& event : f.events_) save_event(out, event);
    save_aliases(out, f.merged_into_);
    std::vector<std::int64_t> sighted;
    for (const auto& entry : f.sightings_) sighted.push_back(entry.first);
    std::sort(sighted.begin(), sighted.end());
    out.count(sighted.size());
    for (const std::int64_t id : sighted) {
      const Sightings& sightings = f.sightings_.at(id);
      out.pod(id);
      out.pod(sightings.scans);
      out.ids(sightings.seen_with);
    }
    out.count(f.closed_maps_counters_.size());
    for (const auto& [name, value] : f.closed_maps_counters_) {
      out.text(name);
      out.pod(value);
    }
    save_aliases(out, f.estimate_aliases_);
    out.count(f.fold_joins_.size());
    for (const JoinEvent& event : f.fold_joins_) save_event(out, event);
    out.count(f.side_joins_.size());
    for (const JoinEvent& event : f.side_joins_) save_event(out, event);
    save_tree(out, f);
    save_stats(out, f.stats_);
  }

  static std::unique_ptr<DCSlam> load_dc(Reader& in) {
    auto f = std::make_unique<DCSlam>(load_config(in));
    f->local_ = load_ekf(in);
    std::unique_lock<std::mutex> lock(f->mutex_);
    f->local_map_steps_ = in.pod<std::int64_t>();
    f->steps_ = in.pod<std::int64_t>();
    f->predictions_ = in.pod<std::int64_t>();
    f->closed_local_maps_ = in.pod<std::int64_t>();
    f->steps_in_closed_maps_ = in.pod<std::int64_t>();
    const bool localised = in.flag();
    Vec3 localised_base;
    for (Eigen::Index k = 0; k < 3; ++k) localised_base(k) = in.pod<double>();
    if (localised) f->localised_base_ = localised_base;
    f->online_localisations_ = in.pod<std::int64_t>();
    std::optional<DCSlam::PendingLocalisation> localisation;
    if (in.flag()) localisation = load_localisation(in, *f);
    f->joins_created_ = in.pod<int>();
    Reader::require(f->joins_created_ >= 0 && f->joins_created_ < (1 << 24), "the number of joins");
    std::vector<std::shared_ptr<DCSlam::JoinTask>> tasks(static_cast<std::size_t>(f->joins_created_));
    f->stack_.resize(in.count(8));
    for (auto& node : f->stack_) node = load_node(in, tasks, 0);
    const std::size_t queued = in.count(4);
    for (std::size_t k = 0; k < queued; ++k) {
      const int index = in.pod<int>();
      Reader::require(index >= 0 && index < f->joins_created_ && tasks[static_cast<std::size_t>(index)],
                      "a queued join that is not pending");
      f->queue_.push_back(tasks[static_cast<std::size_t>(index)]);
    }
    f->events_.resize(in.count(64));
    for (JoinEvent& event : f->events_) event = load_event(in);
    Reader::require(f->events_.size() == static_cast<std::size_t>(f->joins_created_), "join events and joins differ");
    f->merged_into_ = load_aliases(in);
    const std::size_t sighted = in.count(20);
    for (std::size_t k = 0; k < sighted; ++k) {
      const auto id = in.pod<std::int64_t>();
      const int scans = in.pod<int>();
      f->sightings_[id] = Sightings{scans, in.ids()};
    }
    const std::size_t counters = in.count(16);
    for (std::size_t k = 0; k < counters; ++k) {
      std::string name = in.text();
      f->closed_maps_counters_[name] = in.pod<double>();
    }
    f->estimate_aliases_ = load_aliases(in);
    f->fold_joins_.resize(in.count(8));
    for (JoinEvent& event : f->fold_joins_) event = load_event(in);
    f->side_joins_.resize(in.count(8));
    for (JoinEvent& event : f->side_joins_) event = load_event(in);
    load_tree(in, *f);
    f->stats_ = load_stats(in);
    in.finish();
    // Redo the work the saved localisation had done, with the budgets it had been given.
    if (localisation) {
      Reader::require(f->config_.online_localisation_sigma.has_value(), "a localisation without online_localisation_sigma");
      f->resume_localisation(std::move(localisation));
      Reader::require(!f->localisation_->done(), "a localisation under way that its budgets finish");
    }
    // Redo the work the saved joins had done, with the budgets they had been given.
    for (const auto& task : f->queue_) {
      const std::vector<std::int64_t> budgets = std::move(task->budgets);
      task->budgets.clear();
      for (const std::int64_t budget : budgets) {
        lock.unlock();
        f->work_on(*task, budget);
        lock.lock();
      }
      Reader::require(!task->join || !task->join->done(), "a queued join that its budgets finish");
    }
    lock.unlock();
    f->work_ready_.notify_all();
    return f;
  }
};

std::string save_checkpoint(const EkfSlam& filter) {
  Writer out;
  CheckpointAccess::save(out, filter);
  return out.finish(kEkfKind);
}

std::string save_checkpoint(const DCSlam& filter) {
  Writer out;
  CheckpointAccess::save(out, filter);
  return out.finish(kDcKind);
}

std::unique_ptr<EkfSlam> load_ekf_checkpoint(std::string_view bytes) {
  Reader in(bytes, kEkfKind, "an EkfSlam");
  auto filter = CheckpointAccess::load_ekf(in);
  in.finish();
  return filter;
}

std::unique_ptr<DCSlam> load_dc_checkpoint(std::string_view bytes) {
  Reader in(bytes, kDcKind, "a DCSlam");
  return CheckpointAccess::load_dc(in);
}

}  // namespace dcslam
