#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <gtest/gtest.h>

#include "dcslam/core/errors.hpp"
#include "dcslam/datasets/simulator.hpp"
#include "dcslam/estimation/ekf_slam.hpp"
#include "dcslam/joining/dc_slam.hpp"
#include "dcslam/joining/parallel_tasks.hpp"
#include "print_parameters.hpp"

namespace dcslam {
namespace {

using Index = Eigen::Index;

// A linear-Gaussian run (docs/design.md §4.7): Cartesian point observations and a known heading
// (zero heading variance), so the EKF and D&C must agree exactly. The robot drives a
// rounded square loop twice over a grid of landmarks, closing the loop. Noise is the paper's
// (docs/design.md §7): odometry sigma 0.10 m along and 0.05 m across; the point sensor's sigma is
// that of a range of 5 % and a bearing of 1 degree at 2 m (0.10 m along the beam, 0.05 m
// across it). With the 1.5 m grid spacing this keeps joins without ids unambiguous: the pair
// standard deviation at a join is at most about 0.15 m, so the 0.99 gate (3.03 sigma) of a
// landmark never reaches its neighbours.
// `truth`, if given, receives the true pose after each step (truth[0] the start).
std::vector<SlamStep> linear_gaussian_run(int steps, std::uint64_t seed,
                                          std::vector<Vec3>* truth_poses = nullptr) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  std::vector<Vec2> landmarks;
  for (int i = -2; i <= 12; ++i)
    for (int j = -2; j <= 12; ++j) landmarks.emplace_back(1.5 * i + 0.3 * j, 1.5 * j);
  const Mat3 Q = Vec3(0.01, 0.0025, 0.0).asDiagonal();
  const Mat2 R = Vec2(0.01, 0.0025).asDiagonal();
  Vec3 truth = Vec3::Zero();
  if (truth_poses) *truth_poses = {truth};
  std::vector<SlamStep> run;
  for (int k = 0; k < steps; ++k) {
    SlamStep step;
    const bool turn = (k % 15) == 14;
    const Vec3 u_true(1.0, 0.0, turn ? 1.5707963267948966 : 0.0);
    truth = compose(truth, u_true);
    if (truth_poses) truth_poses->push_back(truth);
    step.u = u_true + Vec3(std::sqrt(Q(0, 0)) * normal(rng), std::sqrt(Q(1, 1)) * normal(rng), 0.0);
    step.Q = Q;
    std::vector<Vec2> z;
    for (std::size_t id = 0; id < landmarks.size(); ++id) {
      const Vec2 local = inverse_transform_point(truth, landmarks[id]);
      if (local.norm() > 3.0) continue;
      z.push_back(local + Vec2(std::sqrt(R(0, 0)) * normal(rng), std::sqrt(R(1, 1)) * normal(rng)));
      step.landmark_ids.push_back(static_cast<std::int64_t>(id));
    }
    step.z.resize(static_cast<Index>(z.size()), 2);
    for (std::size_t i = 0; i < z.size(); ++i) step.z.row(static_cast<Index>(i)) = z[i].transpose();
    step.R = {R};
    step.has_landmark_ids = true;
    run.push_back(std::move(step));
  }
  return run;
}

SlamConfig linear_config(int local_map_features) {
  SlamConfig config;
  config.observation = ObservationModel::Point;
  config.association = Association::Known;
  config.join_association = JoinAssociation::Known;
  config.local_map_features = local_map_features;
  return config;
}

// Max |a - b| relative to max |b| over state and covariance, matching features by id.
double relative_difference(const Estimate& a, const Estimate& b) {
  std::map<std::int64_t, Index> index_in_a;
  for (std::size_t k = 0; k < a.landmark_ids.size(); ++k) index_in_a[a.landmark_ids[k]] = static_cast<Index>(k);
  EXPECT_EQ(a.landmark_ids.size(), b.landmark_ids.size());
  std::vector<Index> order = {0, 1, 2};  // b's state order, in a's indices
  for (std::int64_t id : b.landmark_ids) {
    const Index k = index_in_a.at(id);
    order.push_back(3 + 2 * k);
    order.push_back(4 + 2 * k);
  }
  Eigen::VectorXd xa(order.size()), xb(order.size());
  xb << b.robot, Eigen::Map<const Eigen::VectorXd>(b.landmarks.data(), b.landmarks.size());
  Eigen::VectorXd xa_full(a.covariance.rows());
  xa_full << a.robot, Eigen::Map<const Eigen::VectorXd>(a.landmarks.data(), a.landmarks.size());
  double dx = 0, dP = 0;
  for (std::size_t i = 0; i < order.size(); ++i) {
    dx = std::max(dx, std::abs(xa_full(order[i]) - xb(static_cast<Index>(i))));
    for (std::size_t j = 0; j < order.size(); ++j) {
      dP = std::max(dP, std::abs(a.covariance(order[i], order[j]) -
                                 b.covariance(static_cast<Index>(i), static_cast<Index>(j))));
    }
  }
  return std::max(dx / xb.cwiseAbs().maxCoeff(), dP / b.covariance.cwiseAbs().maxCoeff());
}

Estimate run_ekf(const std::vector<SlamStep>& run) {
  EkfSlam ekf(linear_config(1));
  run_steps(ekf, run);
  return ekf.estimate();
}

// Landmark ids, robot, landmarks and covariance equal bit for bit; `where` names the run.
void expect_bitwise_equal(const Estimate& a, const Estimate& b, const std::string& where = "") {
  SCOPED_TRACE(where);
  EXPECT_EQ(a.landmark_ids, b.landmark_ids);
  EXPECT_TRUE((a.robot.array() == b.robot.array()).all());
  EXPECT_TRUE(a.landmarks.size() == b.landmarks.size() && (a.landmarks.array() == b.landmarks.array()).all());
  EXPECT_TRUE(a.covariance.size() == b.covariance.size() && (a.covariance.array() == b.covariance.array()).all());
}

enum class Mode { Immediate, Amortized, Threaded };

SlamConfig in_mode(SlamConfig config, Mode mode) {
  config.amortize = mode == Mode::Amortized;
  config.threaded_joins = mode == Mode::Threaded;
  return config;
}

SlamConfig mode_config(int p, Mode mode) { return in_mode(linear_config(p), mode); }

const char* mode_name(Mode mode) {
  switch (mode) {
    case Mode::Immediate: return "immediate";
    case Mode::Amortized: return "amortized";
    case Mode::Threaded: return "threaded";
  }
  return "?";
}

struct DcCase {
  int local_map_features;
  Mode mode;
};

// The cases print as text: without a PrintTo gtest prints their raw bytes, and CTest puts
// the printed value in the test name.
void PrintTo(Mode mode, std::ostream* out) { *out << mode_name(mode); }
void PrintTo(const DcCase& c, std::ostream* out) {
  *out << "features" << c.local_map_features << "_" << mode_name(c.mode);
}
// The cases' test names are that text too (".../features4_threaded", not ".../6"), so that a
// filter (tools/run_sanitizers.sh's) selects cases by what they are, whatever their order.
struct CaseName {
  template <class Param>
  std::string operator()(const ::testing::TestParamInfo<Param>& info) const {
    return ::testing::PrintToString(info.param);
  }
};

class DcSlamLinear : public ::testing::TestWithParam<DcCase> {};

TEST_P(DcSlamLinear, EqualsEkfExactly) {
  const auto run = linear_gaussian_run(130, 3);
  const Estimate ekf = run_ekf(run);
  DCSlam dc(mode_config(GetParam().local_map_features, GetParam().mode));
  run_steps(dc, run);
  const Estimate est = dc.estimate();
  EXPECT_GT(ekf.landmark_ids.size(), 60u);
  EXPECT_LT(relative_difference(est, ekf), 1e-9);
  EXPECT_GT(dc.joins().size(), 2u);
}

// The re-linearised tree (tree_relinearisation, join_tree.hpp) starts its one pass where the
// tree is already exact in the linear case, so the pass must keep the EKF's answer.
TEST(DcSlamTree, OnePassKeepsTheLinearCaseExact) {
  const auto run = linear_gaussian_run(130, 3);
  const Estimate ekf = run_ekf(run);
  for (const int features : {4, 25}) {
    SlamConfig config = mode_config(features, Mode::Amortized);
    config.tree_relinearisation = 1;
    DCSlam dc(config);
    run_steps(dc, run);
    EXPECT_LT(relative_difference(dc.estimate(), ekf), 1e-9) << features;
    EXPECT_EQ(dc.stats().counters.at("relinearisation_passes"), 1.0);
  }
}

INSTANTIATE_TEST_SUITE_P(
    LocalMapSizes, DcSlamLinear,
    ::testing::Values(DcCase{4, Mode::Immediate}, DcCase{10, Mode::Immediate},
                      DcCase{25, Mode::Immediate}, DcCase{4, Mode::Amortized},
                      DcCase{10, Mode::Amortized}, DcCase{25, Mode::Amortized},
                      DcCase{4, Mode::Threaded}, DcCase{10, Mode::Threaded},
                      DcCase{25, Mode::Threaded}),
    CaseName());

// Step k of `run` given to each filter in turn.
void step_each(const std::vector<SlamStep>& run, std::size_t k, std::initializer_list<SlamFilter*> filters) {
  const std::vector<SlamStep> one(run.begin() + static_cast<std::ptrdiff_t>(k),
                                  run.begin() + static_cast<std::ptrdiff_t>(k) + 1);
  for (SlamFilter* filter : filters) run_steps(*filter, one);
}

class DcSlamAnytime : public ::testing::TestWithParam<Mode> {};

TEST_P(DcSlamAnytime, EstimateMatchesEkfAtAnyStepWithoutDisturbingTheRun) {
  const Mode mode = GetParam();
  const auto run = linear_gaussian_run(60, 11);
  EkfSlam ekf(linear_config(1));
  DCSlam dc(mode_config(6, mode));
  DCSlam undisturbed(mode_config(6, mode));
  int exact_pose_checks = 0;
  for (std::size_t k = 0; k < run.size(); ++k) {
    step_each(run, k, {&ekf, &dc, &undisturbed});
    if (k % 7 == 0) {
      EXPECT_LT(relative_difference(dc.estimate(), ekf.estimate()), 1e-9) << k;
    }
    // With one map on the stack and a local map just opened at the robot, the cheap pose
    // involves no pending join: it must be the EKF's pose.
    if (mode == Mode::Immediate && dc.stack_shape().size() == 1 &&
        dc.local_map().map().robot().isZero() && !dc.joins().empty()) {
      EXPECT_LT((dc.pose() - ekf.pose()).cwiseAbs().maxCoeff(), 1e-9) << k;
      ++exact_pose_checks;
    }
  }
  if (mode == Mode::Immediate) {
    EXPECT_GE(exact_pose_checks, 2);
  }
  undisturbed.finish_joins();
  dc.finish_joins();
  expect_bitwise_equal(dc.estimate(), undisturbed.estimate());
}

INSTANTIATE_TEST_SUITE_P(Modes, DcSlamAnytime,
                         ::testing::Values(Mode::Immediate, Mode::Amortized, Mode::Threaded), CaseName());

// SlamConfig::online_localisation_sigma, in the linear case with ids: the EKF's pose is the exact
// posterior mean, the chain of the stack's maps ignores every pairing its joins have not made
// yet, and the localisation adds those of each closed local map with the oldest map. So the
// localised online pose is nearer the EKF's; the maps and the estimate are those of the plain
// run, bit for bit; and where every map is joined into one, the pose is the chain's, the EKF's.
// Threaded, the online pose depends on when the worker finishes a join, so only the maps are
// compared (and ThreadSanitizer sees the localisations read the stack beside the worker).
TEST(DcSlamOnlineLocalisation, BringsThePoseNearerTheExactOneAndLeavesTheMapsAlone) {
  for (const Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    const auto run = linear_gaussian_run(130, 5);
    EkfSlam ekf(linear_config(1));
    DCSlam plain(mode_config(6, mode));
    SlamConfig config = mode_config(6, mode);
    config.online_localisation_sigma = std::numeric_limits<double>::infinity();
    DCSlam localised(config);
    double plain_error = 0.0, localised_error = 0.0;
    int exact_pose_checks = 0;
    for (std::size_t k = 0; k < run.size(); ++k) {
      step_each(run, k, {&ekf, &plain, &localised});
      plain_error += (plain.pose() - ekf.pose()).head<2>().norm();
      localised_error += (localised.pose() - ekf.pose()).head<2>().norm();
      if (mode == Mode::Immediate && localised.stack_shape().size() == 1 &&
          localised.local_map().map().robot().isZero() && !localised.joins().empty()) {
        EXPECT_LT((localised.pose() - ekf.pose()).cwiseAbs().maxCoeff(), 1e-9) << k;
        ++exact_pose_checks;
      }
    }
    EXPECT_GT(localised.stats().counters.at("online_localisations"), 5.0) << mode_name(mode);
    if (mode != Mode::Threaded) {
      EXPECT_LT(localised_error, 0.7 * plain_error) << mode_name(mode);
    }
    if (mode == Mode::Immediate) {
      EXPECT_GE(exact_pose_checks, 2);
    }
    plain.finish_joins();
    localised.finish_joins();
    expect_bitwise_equal(plain.estimate(), localised.estimate(), mode_name(mode));
  }
}

// The run of tests/python/test_join_failures.py: local maps of one feature, closing every four
// steps, and no motion noise. Steps 9 and 13 see landmark 1000 at a range of 1e-300: the join
// of their local maps (queued by step 13's update) fails on that pair.
std::vector<SlamStep> failing_join_run() {
  std::vector<SlamStep> run;
  for (std::int64_t k = 0; k < 40; ++k) {
    SlamStep step;
    step.u = Vec3(0.3, 0.0, 0.0);
    step.R = {Vec2(0.01, 0.001).asDiagonal()};
    step.has_landmark_ids = true;
    if (k == 9 || k == 13) {
      step.z.resize(1, 2);
      step.z << 1e-300, 0.0;
      step.landmark_ids = {1000};
    } else if (k % 4 == 1) {
      step.z.resize(k < 4 ? 1 : 2, 2);
      step.z.row(0) << 2.0, 0.4;
      step.landmark_ids = {k};
      if (k >= 4) {
        step.z.row(1) << 2.5, -0.3;
        step.landmark_ids.push_back(k - 4);
      }
    } else {
      step.z.resize(0, 2);
    }
    run.push_back(std::move(step));
  }
  return run;
}

// A failed join is raised, the filter is back before the update that queued it, and fed the
// steps again without that update it ends bitwise as a filter that never saw it. Also run
// under TSan (tools/run_sanitizers.sh): the roll-back meets the worker thread.
TEST(DcSlam, AFailedJoinRollsBackInEveryMode) {
  const auto run = failing_join_run();
  for (const Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    SlamConfig config;
    config.association = Association::Known;
    config.join_association = JoinAssociation::Known;
    config.local_map_features = 1;
    config.amortize = mode != Mode::Immediate;
    config.threaded_joins = mode == Mode::Threaded;
    DCSlam dc(config);
    std::int64_t skipped = -1;
    int failures = 0;
    std::size_t k = 0;
    bool predicted = false;  // step k's predict is done
    while (true) {
      try {
        if (k == run.size()) {
          dc.finish_joins();
          break;
        }
        if (!predicted) dc.predict(run[k].u, run[k].Q);
        predicted = true;
        if (static_cast<std::int64_t>(k) != skipped) dc.update(run[k].z, run[k].R, &run[k].landmark_ids);
        ++k;
        predicted = false;
      } catch (const InvalidArgument& error) {
        const std::string message = error.what();
        const std::string marker = "queued the join (step ";
        const auto at = message.find(marker);
        ASSERT_NE(at, std::string::npos) << message;
        EXPECT_NE(message.find("positive definite"), std::string::npos) << message;
        skipped = std::stoll(message.substr(at + marker.size())) - 1;  // steps count predicts from 1
        ++failures;
        k = static_cast<std::size_t>(skipped);  // back before that step's update, after its predict
        predicted = true;
      }
    }
    EXPECT_EQ(failures, 1) << mode_name(mode);
    EXPECT_EQ(skipped, 13) << mode_name(mode);
    DCSlam oracle(config);
    for (std::size_t j = 0; j < run.size(); ++j) {
      oracle.predict(run[j].u, run[j].Q);
      if (j != 13) oracle.update(run[j].z, run[j].R, &run[j].landmark_ids);
    }
    oracle.finish_joins();
    expect_bitwise_equal(dc.estimate(), oracle.estimate(), mode_name(mode));
  }
}

TEST(DcSlam, ImmediateAmortizedAndThreadedAreBitwiseIdentical) {
  const auto run = linear_gaussian_run(150, 5);
  std::vector<Estimate> results;
  for (Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    DCSlam dc(mode_config(8, mode));
    run_steps(dc, run);
    dc.finish_joins();
    results.push_back(dc.estimate());
    if (mode == Mode::Amortized) {
      // Joins really were spread out: at least one finished after the step it was created in.
      bool spread = false;
      for (const JoinEvent& e : dc.joins()) spread |= e.step_finished > e.step_created;
      EXPECT_TRUE(spread);
    }
  }
  for (std::size_t m = 1; m < results.size(); ++m) expect_bitwise_equal(results[m], results[0]);
}

// A small square loop driven several times (160 steps, 10 % clutter, seed 0).
Simulation small_loop_laps() {
  SimulationConfig scene;
  scene.trajectory = Trajectory::Loop;
  scene.steps = 160;
  scene.side_steps = 10;
  scene.clutter = 0.1;
  return simulate(scene);
}

// Every step of `sim` into `dc` without ids; the ids update() returned, and `after_step` called
// after each update.
std::vector<std::int64_t> run_without_ids(DCSlam& dc, const Simulation& sim,
                                          const std::function<void()>& after_step = [] {}) {
  std::vector<std::int64_t> returned;
  for (Eigen::Index k = 0; k < sim.odometry.rows(); ++k) {
    dc.predict(sim.odometry.row(k).transpose(), sim.odometry_covariance);
    const auto begin = sim.step_offsets[static_cast<std::size_t>(k)];
    const auto count = sim.step_offsets[static_cast<std::size_t>(k) + 1] - begin;
    std::vector<Mat2> R;
    for (Eigen::Index m = begin; m < begin + count; ++m) {
      R.push_back(Eigen::Map<const Eigen::Matrix<double, 2, 2, Eigen::RowMajor>>(sim.measurement_covariances.row(m).data()));
    }
    const MeasurementMatrix z = sim.measurements.middleRows(begin, count);
    const std::vector<std::int64_t> step_ids = dc.update(z, R, nullptr);
    returned.insert(returned.end(), step_ids.begin(), step_ids.end());
    after_step();
  }
  return returned;
}

// Weak joins (join_alternatives.hpp) decide alike whichever way joins run, the worker thread
// included: the simulator's small_loop_laps scene (seed 0), where a later join takes a weak
// join's alternative.
TEST(DcSlam, WeakJoinsDecideAlikeInEveryMode) {
  const Simulation sim = small_loop_laps();
  std::vector<Estimate> results;
  std::vector<std::vector<std::int64_t>> ids;
  for (Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    SlamConfig config;
    config.association = Association::Jcbb;
    config.join_association = JoinAssociation::Rjc;
    // The run traced when this test was written: its local maps reject the measurements
    // they leave unexplained beside mapped or tentative features, as they did then.
    config.new_feature_margin = std::numeric_limits<double>::infinity();
    config.new_feature_beside_tentative = false;
    DCSlam dc(in_mode(config, mode));
    const std::vector<std::int64_t> returned = run_without_ids(dc, sim);
    dc.finish_joins();
    int taken = 0;
    for (const JoinEvent& event : dc.joins()) taken += event.report.alternatives_taken;
    EXPECT_GT(taken, 0) << mode_name(mode);
    results.push_back(dc.estimate());
    ids.push_back(dc.resolve(returned));
  }
  for (std::size_t m = 1; m < results.size(); ++m) {
    EXPECT_EQ(ids[m], ids[0]);
    expect_bitwise_equal(results[m], results[0]);
  }
}

// estimate()'s independent work side by side (parallel_tasks.hpp): every task runs once,
// nested calls share the outermost call's threads, and a failure is reported after every
// task has run. Here so that ThreadSanitizer runs it (dcslam_thread_tests).
TEST(RunTasks, RunsEveryTaskOnceOnNoMoreThreadsThanAsked) {
  for (int threads : {1, 2, 3}) {
    std::atomic<int> running{0}, most{0};
    std::vector<std::atomic<int>> runs(4 * 5);
    const auto task = [&](std::size_t k) {
      const int now = ++running;
      for (int seen = most.load(); now > seen && !most.compare_exchange_weak(seen, now);) {
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));  // long enough to overlap
      ++runs[k];
      --running;
    };
    std::vector<std::function<void()>> outer;
    for (std::size_t a = 0; a < 4; ++a) {
      outer.emplace_back([&, a] {
        std::vector<std::function<void()>> inner;
        for (std::size_t b = 0; b < 5; ++b) inner.emplace_back([&, a, b] { task(5 * a + b); });
        run_tasks(inner, threads);
      });
    }
    run_tasks(outer, threads);
    for (const std::atomic<int>& count : runs) EXPECT_EQ(count.load(), 1) << threads << " threads";
    EXPECT_LE(most.load(), threads);
    if (threads > 1) {
      EXPECT_GT(most.load(), 1) << "the tasks never ran side by side";
    }
  }
  EXPECT_GE(estimate_thread_count(0), 1);
  EXPECT_EQ(estimate_thread_count(3), 3);
}

TEST(RunTasks, RethrowsTheFirstFailureInTheListsOrderAfterEveryTaskRan) {
  for (int threads : {1, 3}) {
    std::atomic<int> ran{0};
    std::vector<std::function<void()>> tasks;
    for (int k = 0; k < 6; ++k) {
      tasks.emplace_back([&, k] {
        ++ran;
        if (k == 4) throw std::runtime_error("task 4");
        if (k == 2) throw InvalidArgument("task 2");
      });
    }
    try {
      run_tasks(tasks, threads);
      ADD_FAILURE() << "no exception";
    } catch (const InvalidArgument& error) {
      EXPECT_STREQ(error.what(), "task 2");
    }
    EXPECT_EQ(ran.load(), 6);
  }
}

// estimate()'s fold on several threads (SlamConfig::estimate_threads) is bitwise the fold on
// one: the revisit scene loop_both_ways (240 steps, seed 2) without ids, whose fold carries
// each version of a weak fold join through the rest of the fold and takes a version other than
// the first of a batch (a batch folding the wrong version fails here), and whose fold joins
// associate several candidate versions.
TEST(DcSlam, EstimateIsBitwiseTheSameOnAnyNumberOfThreads) {
  SimulationConfig scene;
  scene.trajectory = Trajectory::LoopBothWays;
  scene.steps = 240;
  scene.side_steps = 15;
  scene.clutter = 0.1;
  scene.seed = 2;
  const Simulation sim = simulate(scene);
  std::vector<Estimate> results;
  std::vector<std::vector<std::int64_t>> ids;
  for (int threads : {1, 3}) {
    SlamConfig config;
    config.association = Association::Jcbb;
    config.join_association = JoinAssociation::Rjc;
    config.estimate_threads = threads;
    DCSlam dc(config);
    const std::vector<std::int64_t> returned = run_without_ids(dc, sim);
    dc.finish_joins();
    results.push_back(dc.estimate());
    ids.push_back(dc.resolve(returned));
    int weak = 0;
    for (const JoinEvent& event : dc.fold_joins()) weak += event.report.deferred_pairings > 0 ? 1 : 0;
    EXPECT_GT(weak, 0) << "no weak fold join: the fold compares no versions here";
  }
  for (std::size_t m = 1; m < results.size(); ++m) {
    EXPECT_EQ(ids[m], ids[0]);
    expect_bitwise_equal(results[m], results[0]);
  }
}

// The re-linearised tree's pass on several threads (its leaves' fits and rebuilds, the joins
// of disjoint subtrees and the fill of each join's result side by side) gives bitwise the
// pass made on one: small_loop_laps without ids, one and three threads.
TEST(DcSlamTree, OnePassIsBitwiseTheSameOnAnyNumberOfThreads) {
  const Simulation sim = small_loop_laps();
  std::vector<Estimate> results;
  for (int threads : {1, 3}) {
    SlamConfig config;
    config.association = Association::Jcbb;
    config.join_association = JoinAssociation::Rjc;
    config.tree_relinearisation = 1;
    config.estimate_threads = threads;
    DCSlam dc(config);
    run_without_ids(dc, sim);
    results.push_back(dc.estimate());
    EXPECT_EQ(dc.stats().counters.at("relinearisation_passes"), 1.0);
    EXPECT_GT(dc.joins().size(), 8u);
  }
  expect_bitwise_equal(results[1], results[0]);
}

// estimate() while a join is pending computes that join on the side, and a later estimate()
// takes it as computed while the join is still pending (DCSlam::MaterializedJoin): called at
// every step, amortized and threaded runs give bitwise the estimate and resolved ids of the
// immediate run at that step, where no join is pending, with merges after small joins to
// replay (join_merge_max_leaves) and weak joins' versions in the reused maps, some calls
// computing a join after one they took as computed (side_joins() tells which).
TEST(DcSlam, EstimateAtEveryStepReusesPendingJoinsExactly) {
  const Simulation sim = small_loop_laps();
  SlamConfig config;
  config.association = Association::Jcbb;
  config.join_association = JoinAssociation::Rjc;
  config.join_merge_max_leaves = 4;
  std::vector<Estimate> expected;  // the immediate run's, at the same steps
  std::vector<std::int64_t> expected_ids;
  for (Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    DCSlam dc(in_mode(config, mode));
    std::size_t step = 0, calls = 0;
    int reused_then_computed = 0;  // calls that computed a join after one they took as computed
    const std::vector<std::int64_t> returned = run_without_ids(dc, sim, [&] {
      if (++step % 3 != 0) return;  // every third step: a pending join lasts several
      const Estimate estimate = dc.estimate();
      if (mode == Mode::Immediate) {
        expected.push_back(estimate);
        return;
      }
      int first_reused = -1, last_computed = -1;
      for (const JoinEvent& event : dc.side_joins()) {
        if (event.step_finished < static_cast<std::int64_t>(step) && first_reused < 0) first_reused = event.index;
        if (event.step_finished == static_cast<std::int64_t>(step)) last_computed = event.index;
      }
      if (first_reused >= 0 && last_computed > first_reused) ++reused_then_computed;
      expect_bitwise_equal(estimate, expected[calls++], std::string(mode_name(mode)) + ", step " + std::to_string(step));
    });
    // resolve() follows the last estimate()'s merges until the next step.
    const Estimate last = dc.estimate();
    const std::map<std::string, double>& counters = dc.stats().counters;
    if (mode == Mode::Immediate) {
      expected.push_back(last);
      expected_ids = dc.resolve(returned);
      EXPECT_EQ(counters.at("estimate_pending_joins"), 0.0);
      continue;
    }
    EXPECT_EQ(dc.resolve(returned), expected_ids) << mode_name(mode);
    EXPECT_EQ(last.landmark_ids, expected.back().landmark_ids) << mode_name(mode);
    EXPECT_EQ(calls + 1, expected.size()) << mode_name(mode);
    // Some pending joins were taken from the call before, not all: each is computed once. (The
    // worker thread may finish every join before the next call: no count to expect there.)
    if (mode == Mode::Threaded) continue;
    EXPECT_GT(counters.at("estimate_pending_joins_reused"), 0.0) << mode_name(mode);
    EXPECT_GE(reused_then_computed, 3) << mode_name(mode);
    EXPECT_LT(counters.at("estimate_pending_joins_reused"), counters.at("estimate_pending_joins")) << mode_name(mode);
  }
}

// Without ids a localisation (its RJC) is resumable work that amortized and threaded joins
// spread over the steps after its closure: it is seen under way between steps, it localises,
// and the maps and ids stay those of the run without it. Also run under TSan: the
// localisation reads the stack's maps while the worker joins them.
TEST(DcSlamOnlineLocalisation, SpreadOverStepsWithoutIds) {
  const Simulation sim = small_loop_laps();
  for (const Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    SlamConfig config;
    config.association = Association::Jcbb;
    config.join_association = JoinAssociation::Rjc;
    config.local_map_features = 60;  // local maps of several steps, so that a localisation spans some
    config = in_mode(config, mode);
    DCSlam plain(config);
    const std::vector<std::int64_t> plain_ids = run_without_ids(plain, sim);
    config.online_localisation_sigma = 10.0;
    DCSlam localised(config);
    int steps_under_way = 0;
    const std::vector<std::int64_t> ids = run_without_ids(
        localised, sim, [&] { steps_under_way += localised.stats().counters.at("localisation_under_way") > 0 ? 1 : 0; });
    EXPECT_GT(localised.stats().counters.at("online_localisations"), 3.0) << mode_name(mode);
    if (mode == Mode::Immediate) {
      EXPECT_EQ(steps_under_way, 0);
    } else {
      EXPECT_GT(steps_under_way, 2) << mode_name(mode);
    }
    EXPECT_EQ(ids, plain_ids) << mode_name(mode);
    plain.finish_joins();
    localised.finish_joins();
    expect_bitwise_equal(plain.estimate(), localised.estimate(), mode_name(mode));
  }
}

// ---------------------------------------------------------------------------------------
// keep_local_map_poses against an independent oracle: one dense EKF over [robot, landmarks,
// copies of the robot], which copies the robot pose into its state wherever a local map
// closes (the state grows by [x; x_R], P by [P, P(:,R); P(R,:), P_RR]). In the linear-Gaussian
// run this is the exact posterior of every past pose, with no local maps and no joins.
class CloningEkf {
 public:
  explicit CloningEkf(int local_map_features) : local_map_features_(local_map_features) {}

  void step(const SlamStep& s) {
    predict(s.u, s.Q);
    update(s);
    // A local map closes once it holds local_map_features landmarks (known ids: every
    // landmark seen since it opened).
    seen_.insert(s.landmark_ids.begin(), s.landmark_ids.end());
    if (static_cast<int>(seen_.size()) >= local_map_features_) {
      clone_robot(steps_);
      seen_.clear();
    }
  }

  const Eigen::VectorXd& x() const { return x_; }
  const Eigen::MatrixXd& P() const { return P_; }
  const std::map<std::int64_t, Index>& landmark_rows() const { return landmark_row_; }
  const std::vector<std::pair<std::int64_t, Index>>& clone_rows() const { return clone_rows_; }

 private:
  void predict(const Vec3& u, const Mat3& Q) {
    Mat3 F, G;
    x_.head<3>() = compose(x_.head<3>(), u, &F, &G);
    P_.topRows<3>() = (F * P_.topRows<3>()).eval();
    P_.leftCols<3>() = (P_.leftCols<3>() * F.transpose()).eval();
    P_.topLeftCorner<3, 3>() += G * Q * G.transpose();
    ++steps_;
  }

  void update(const SlamStep& s) {
    const Vec3 robot = x_.head<3>();
    const Index D = x_.size();
    std::vector<Index> paired, fresh;
    for (std::size_t k = 0; k < s.landmark_ids.size(); ++k) {
      (landmark_row_.count(s.landmark_ids[k]) ? paired : fresh).push_back(static_cast<Index>(k));
    }
    const Index m = static_cast<Index>(paired.size());
    if (m > 0) {
      Eigen::MatrixXd H = Eigen::MatrixXd::Zero(2 * m, D), R = Eigen::MatrixXd::Zero(2 * m, 2 * m);
      Eigen::VectorXd innovation(2 * m);
      for (Index a = 0; a < m; ++a) {
        const Index k = paired[static_cast<std::size_t>(a)];
        const Index row = landmark_row_.at(s.landmark_ids[static_cast<std::size_t>(k)]);
        Mat23 J_robot;
        Mat2 J_point;
        const Vec2 predicted = inverse_transform_point(robot, x_.segment<2>(row), &J_robot, &J_point);
        innovation.segment<2>(2 * a) = s.z.row(k).transpose() - predicted;
        H.block<2, 3>(2 * a, 0) = J_robot;
        H.block<2, 2>(2 * a, row) = J_point;
        R.block<2, 2>(2 * a, 2 * a) = s.R.size() == 1 ? s.R[0] : s.R[static_cast<std::size_t>(k)];
      }
      const Eigen::MatrixXd PHt = P_ * H.transpose();
      const Eigen::MatrixXd S = H * PHt + R;
      const Eigen::MatrixXd K = PHt * S.inverse();
      x_ += K * innovation;
      P_ -= K * S * K.transpose();
      P_ = (0.5 * (P_ + P_.transpose())).eval();
    }
    for (Index k : fresh) {
      Mat23 J_robot;
      Mat2 J_z;
      const Vec2 f = transform_point(x_.head<3>(), s.z.row(k).transpose(), &J_robot, &J_z);
      const Mat2 R = s.R.size() == 1 ? s.R[0] : s.R[static_cast<std::size_t>(k)];
      const Index row = grow(2);
      x_.segment<2>(row) = f;
      P_.block(row, 0, 2, row) = J_robot * P_.topRows<3>().leftCols(row);
      P_.block(0, row, row, 2) = P_.block(row, 0, 2, row).transpose();
      P_.block<2, 2>(row, row) =
          J_robot * P_.topLeftCorner<3, 3>() * J_robot.transpose() + J_z * R * J_z.transpose();
      landmark_row_[s.landmark_ids[static_cast<std::size_t>(k)]] = row;
    }
  }

  void clone_robot(std::int64_t id) {
    const Index row = grow(3);
    x_.segment<3>(row) = x_.head<3>();
    P_.block(row, 0, 3, row) = P_.topRows<3>().leftCols(row);
    P_.block(0, row, row, 3) = P_.block(row, 0, 3, row).transpose();
    P_.block<3, 3>(row, row) = P_.topLeftCorner<3, 3>();
    clone_rows_.emplace_back(id, row);
  }

  Index grow(Index extra) {
    const Index row = x_.size();
    x_.conservativeResize(row + extra);
    P_.conservativeResize(row + extra, row + extra);
    return row;
  }

  int local_map_features_;
  std::int64_t steps_ = 0;
  std::set<std::int64_t> seen_;
  Eigen::VectorXd x_ = Eigen::VectorXd::Zero(3);
  Eigen::MatrixXd P_ = Eigen::MatrixXd::Zero(3, 3);
  std::map<std::int64_t, Index> landmark_row_;
  std::vector<std::pair<std::int64_t, Index>> clone_rows_;  // (step, row), oldest first
};

// Max |a - oracle| relative to the oracle's largest entry, over the state and the joint
// covariance (landmarks matched by id, past poses by id), for the mean and covariance apart.
std::pair<double, double> relative_difference(const Estimate& a, const CloningEkf& oracle) {
  std::vector<Index> rows = {0, 1, 2};  // oracle rows, in a's state order
  for (std::int64_t id : a.landmark_ids) {
    const Index row = oracle.landmark_rows().at(id);
    rows.push_back(row);
    rows.push_back(row + 1);
  }
  std::map<std::int64_t, Index> clone_row(oracle.clone_rows().begin(), oracle.clone_rows().end());
  for (std::int64_t id : a.past_pose_ids) {
    for (Index c = 0; c < 3; ++c) rows.push_back(clone_row.at(id) + c);
  }
  const Index d = static_cast<Index>(rows.size());
  EXPECT_EQ(a.covariance.rows(), d);
  EXPECT_EQ(oracle.x().size(), d);
  Eigen::VectorXd xa(d);
  xa << a.robot, Eigen::Map<const Eigen::VectorXd>(a.landmarks.data(), a.landmarks.size()),
      Eigen::Map<const Eigen::VectorXd>(a.past_poses.data(), a.past_poses.size());
  // Headings (the robot's, each past pose's) compare modulo 2π: pi and -pi are one heading.
  const Index poses_begin = 3 + 2 * static_cast<Index>(a.landmark_ids.size());
  const auto is_heading = [&](Index i) { return i == 2 || (i >= poses_begin && (i - poses_begin) % 3 == 2); };
  double dx = 0, dP = 0;
  for (Index i = 0; i < d; ++i) {
    const double difference = xa(i) - oracle.x()(rows[static_cast<std::size_t>(i)]);
    dx = std::max(dx, std::abs(is_heading(i) ? wrap_angle(difference) : difference));
    for (Index j = 0; j < d; ++j) {
      dP = std::max(dP, std::abs(a.covariance(i, j) - oracle.P()(rows[static_cast<std::size_t>(i)],
                                                                  rows[static_cast<std::size_t>(j)])));
    }
  }
  return {dx / oracle.x().cwiseAbs().maxCoeff(), dP / oracle.P().cwiseAbs().maxCoeff()};
}

class DcSlamPastPoses : public ::testing::TestWithParam<DcCase> {};

TEST_P(DcSlamPastPoses, EqualTheCloningEkfAtEveryStepAndSitNearTheTruth) {
  std::vector<Vec3> truth;
  const auto run = linear_gaussian_run(130, 3, &truth);
  SlamConfig config = mode_config(GetParam().local_map_features, GetParam().mode);
  config.keep_local_map_poses = true;
  DCSlam dc(config);
  CloningEkf oracle(GetParam().local_map_features);
  for (std::size_t k = 0; k < run.size(); ++k) {
    run_steps(dc, {run[k]});
    oracle.step(run[k]);
    if (k % 20 != 19 && k + 1 != run.size()) continue;
    const Estimate est = dc.estimate();  // anytime: pending joins done on copies
    std::vector<std::int64_t> oracle_ids;
    for (const auto& clone : oracle.clone_rows()) oracle_ids.push_back(clone.first);
    EXPECT_EQ(est.past_pose_ids, oracle_ids) << k;
    const auto [dx, dP] = relative_difference(est, oracle);
    EXPECT_LT(dx, 1e-9) << k;
    EXPECT_LT(dP, 1e-9) << k;
  }
  const Estimate est = dc.estimate();
  const Index m = est.past_poses.rows();
  EXPECT_EQ(static_cast<double>(m), dc.stats().counters.at("local_maps_closed"));
  EXPECT_GT(m, 3);
  const Index poses_begin = 3 + 2 * static_cast<Index>(est.landmark_ids.size());
  for (Index q = 0; q < m; ++q) {
    // Ground truth: the known heading exactly, the position well within its covariance.
    const Vec3 true_pose = truth[static_cast<std::size_t>(est.past_pose_ids[static_cast<std::size_t>(q)])];
    const Vec3 pose = est.past_poses.row(q).transpose();
    EXPECT_LT(std::abs(wrap_angle(pose.z() - true_pose.z())), 1e-9);
    const Mat2 covariance = est.covariance.block<2, 2>(poses_begin + 3 * q, poses_begin + 3 * q);
    const Vec2 error = pose.head<2>() - true_pose.head<2>();
    EXPECT_LT(error.dot(covariance.ldlt().solve(error)), 25.0) << q;
  }
}

INSTANTIATE_TEST_SUITE_P(
    LocalMapSizes, DcSlamPastPoses,
    ::testing::Values(DcCase{4, Mode::Immediate}, DcCase{10, Mode::Immediate},
                      DcCase{25, Mode::Immediate}, DcCase{4, Mode::Amortized},
                      DcCase{10, Mode::Amortized}, DcCase{25, Mode::Amortized},
                      DcCase{4, Mode::Threaded}, DcCase{10, Mode::Threaded},
                      DcCase{25, Mode::Threaded}),
    CaseName());

TEST(DcSlam, PastPosesAreBitwiseTheSameInEveryJoinMode) {
  const auto run = linear_gaussian_run(150, 5);
  std::vector<Estimate> results;
  for (Mode mode : {Mode::Immediate, Mode::Amortized, Mode::Threaded}) {
    SlamConfig config = mode_config(8, mode);
    config.keep_local_map_poses = true;
    DCSlam dc(config);
    run_steps(dc, run);
    dc.finish_joins();
    results.push_back(dc.estimate());
  }
  ASSERT_GT(results[0].past_poses.rows(), 5);
  for (std::size_t m = 1; m < results.size(); ++m) {
    EXPECT_EQ(results[m].past_pose_ids, results[0].past_pose_ids);
    EXPECT_TRUE((results[m].past_poses.array() == results[0].past_poses.array()).all());
    expect_bitwise_equal(results[m], results[0]);
  }
  // Off by default: no past poses, the covariance is [robot, landmarks] only.
  DCSlam plain(mode_config(8, Mode::Immediate));
  run_steps(plain, run);
  const Estimate est = plain.estimate();
  EXPECT_EQ(est.past_poses.rows(), 0);
  EXPECT_TRUE(est.past_pose_ids.empty());
  EXPECT_EQ(est.covariance.rows(), 3 + 2 * static_cast<Index>(est.landmark_ids.size()));
}

TEST(DcSlam, StackFollowsAlgorithm2) {
  const auto run = linear_gaussian_run(130, 3);
  DCSlam dc(mode_config(5, Mode::Immediate));
  run_steps(dc, run);
  // Binary counter: the stack's leaf counts are distinct powers of two, decreasing upwards.
  const auto shape = dc.stack_shape();
  ASSERT_FALSE(shape.empty());
  for (std::size_t i = 0; i < shape.size(); ++i) {
    const int leaves = shape[i].first;
    EXPECT_EQ(leaves & (leaves - 1), 0);
    if (i > 0) {
      EXPECT_LT(leaves, shape[i - 1].first);
    }
  }
}

}  // namespace
}  // namespace dcslam

namespace dcslam {
namespace {

// Without ids at joins, JCBB and RJC must pair features of the same landmark (the local maps
// keep the true ids, so a wrong merge shows as resolve(id) != id) and miss few true pairs
// (a missed pair leaves the landmark twice in the final map).
class DcSlamJoinAssociation : public ::testing::TestWithParam<JoinAssociation> {};

// Pairs imposed by the joins that estimate() runs on copies of the stack: they never appear
// in joins(), but each removes one feature from the sum of the stack's maps.
std::int64_t stack_join_pairings(const DCSlam& dc, const Estimate& estimate) {
  std::int64_t features_on_stack = 0;
  for (const auto& [leaves, features] : dc.stack_shape()) features_on_stack += features;
  return features_on_stack - static_cast<std::int64_t>(estimate.landmark_ids.size());
}

TEST_P(DcSlamJoinAssociation, PairsTrueFeaturesOnly) {
  const auto run = linear_gaussian_run(130, 3);
  SlamConfig by_id = mode_config(10, Mode::Immediate);
  SlamConfig unknown = by_id;
  unknown.join_association = GetParam();
  DCSlam reference(by_id), dc(unknown);
  run_steps(reference, run);
  run_steps(dc, run);
  const auto joins = dc.joins(), reference_joins = reference.joins();
  ASSERT_EQ(joins.size(), reference_joins.size());
  std::int64_t pairings = 0, true_pairings = 0;
  for (std::size_t k = 0; k < joins.size(); ++k) {
    EXPECT_GE(joins[k].report.overlap, joins[k].report.pairings);
    pairings += joins[k].report.pairings;
    true_pairings += reference_joins[k].report.pairings;
    // RJC's randomized path runs on overlaps larger than 3b (smaller ones go to JCBB).
    if (GetParam() == JoinAssociation::Rjc && joins[k].report.overlap > 12) {
      EXPECT_GT(joins[k].report.tries, 0);
    }
  }
  const Estimate estimate = dc.estimate(), reference_estimate = reference.estimate();
  pairings += stack_join_pairings(dc, estimate);
  true_pairings += stack_join_pairings(reference, reference_estimate);
  std::set<std::int64_t> distinct(estimate.landmark_ids.begin(), estimate.landmark_ids.end());
  EXPECT_EQ(dc.resolve(estimate.landmark_ids), estimate.landmark_ids);  // no wrong merge
  for (const auto& id : reference_estimate.landmark_ids) EXPECT_EQ(dc.resolve({id})[0], id);
  EXPECT_EQ(distinct.size(), reference_estimate.landmark_ids.size());
  const auto duplicates = static_cast<std::int64_t>(estimate.landmark_ids.size() - distinct.size());
  EXPECT_GE(true_pairings, 300);
  EXPECT_LE(pairings, true_pairings);
  EXPECT_GE(pairings, 0.98 * true_pairings);  // a 0.99 gate rejects ~1% of true pairs
  EXPECT_EQ(duplicates, true_pairings - pairings);
}

INSTANTIATE_TEST_SUITE_P(Modes, DcSlamJoinAssociation,
                         ::testing::Values(JoinAssociation::Jcbb, JoinAssociation::Rjc));

}  // namespace
}  // namespace dcslam

namespace dcslam {
namespace {

// The linear run with unknown association and one spurious point in about a third of the
// scans, placed at least 0.7 m from every landmark the scan sees (so it gates with none of
// them). `truth[k][i]` is the landmark of measurement i of step k, -1 for clutter.
std::vector<SlamStep> cluttered_run(int steps, std::uint64_t seed,
                                    std::vector<std::vector<std::int64_t>>& truth) {
  std::vector<SlamStep> run = linear_gaussian_run(steps, seed);
  std::mt19937_64 rng(seed + 1);
  std::uniform_real_distribution<double> uniform(-2.2, 2.2), chance(0.0, 1.0);
  truth.clear();
  for (SlamStep& step : run) {
    std::vector<std::int64_t> ids = step.landmark_ids;
    if (chance(rng) < 0.35) {
      Vec2 clutter;
      bool clear = false;
      while (!clear) {
        clutter = Vec2(uniform(rng), uniform(rng));
        clear = clutter.norm() <= 2.2;
        for (Index i = 0; clear && i < step.z.rows(); ++i) {
          clear = (step.z.row(i).transpose() - clutter).norm() > 0.7;
        }
      }
      step.z.conservativeResize(step.z.rows() + 1, 2);
      step.z.row(step.z.rows() - 1) = clutter.transpose();
      ids.push_back(-1);
    }
    step.landmark_ids.clear();
    step.has_landmark_ids = false;
    truth.push_back(std::move(ids));
  }
  return run;
}

// A landmark first seen in the step that closes a local map is tentative there; the next
// local map sees it again, and the join between them must keep it as one feature (before,
// closing pruned it and the next map started it again). Unconfirmed clutter survives only in
// the maps no join has judged yet: the local map being built and the newest closed one.
TEST(DcSlamTentative, FeatureFirstSeenAtALocalMapsCloseIsMergedWithItsNextSighting) {
  std::vector<std::vector<std::int64_t>> truth;
  const auto run = cluttered_run(130, 3, truth);
  SlamConfig config = mode_config(10, Mode::Immediate);
  config.association = Association::Jcbb;
  config.join_association = JoinAssociation::Jcbb;
  DCSlam dc(config);
  std::map<std::int64_t, std::int64_t> first_id;  // landmark -> id of its first sighting
  // For landmarks first seen in a step that closed a local map: the id of their sighting in
  // the step after it (in the next local map).
  std::map<std::int64_t, std::int64_t> next_id;
  std::set<std::int64_t> first_seen_at_close, clutter_ids, known_ids;
  std::map<std::int64_t, std::size_t> clutter_step;  // step that started each clutter feature
  std::vector<std::size_t> close_steps;
  double closed = 0;
  std::size_t close_step = run.size();
  for (std::size_t k = 0; k < run.size(); ++k) {
    dc.predict(run[k].u, run[k].Q);
    const auto ids = dc.update(run[k].z, run[k].R, nullptr);
    const bool closes = dc.stats().counters.at("local_maps_closed") > closed;
    closed = dc.stats().counters.at("local_maps_closed");
    const bool after_close = k == close_step + 1;
    if (closes) {
      close_step = k;
      close_steps.push_back(k);
    }
    for (std::size_t i = 0; i < ids.size(); ++i) {
      const std::int64_t landmark = truth[k][i];
      const bool fresh = ids[i] >= 0 && known_ids.insert(ids[i]).second;
      if (landmark < 0) {
        if (fresh) {
          clutter_ids.insert(ids[i]);
          clutter_step[ids[i]] = k;
        }
        continue;
      }
      if (ids[i] < 0) continue;
      if (first_id.emplace(landmark, ids[i]).second) {
        if (closes) first_seen_at_close.insert(landmark);
      } else if (after_close && first_seen_at_close.count(landmark) != 0) {
        next_id.emplace(landmark, ids[i]);
      }
    }
  }
  const Estimate estimate = dc.estimate();
  const std::multiset<std::int64_t> in_estimate(estimate.landmark_ids.begin(),
                                                estimate.landmark_ids.end());
  int merged = 0, missed = 0;
  for (const auto& [landmark, later] : next_id) {
    const std::int64_t second = dc.resolve({later})[0];
    const std::int64_t first = dc.resolve({first_id.at(landmark)})[0];
    // Both sightings wait for the join of their two maps (the second is in the first steps of
    // its map, so it does not expire there); only that join's association leaving the pair
    // unmatched drops them.
    if (first == -1 || second == -1) {
      ++missed;
      continue;
    }
    EXPECT_EQ(in_estimate.count(first), 1u) << landmark;
    // Either a finished join merged them already, or estimate()'s joins do.
    if (second != first) {
      EXPECT_EQ(in_estimate.count(second), 0u) << landmark;
    }
    ++merged;
  }
  EXPECT_GE(merged, 8);
  EXPECT_LE(missed, merged / 4);
  // A clutter feature outside the local map is in the estimate only if another spurious point
  // was paired with it (seen twice, so confirmed), or if a neighbouring local map that could
  // still confirm it is not joined with its own yet: it was seen in the first tentative_window
  // steps of a local map that is the first of its stack node (the previous map is elsewhere),
  // or in the last ones of a map that is the last of its node. Every other one resolves to -1.
  const auto& local_ids = dc.local_map().map().ids();
  const std::set<std::int64_t> in_local_map(local_ids.begin(), local_ids.end());
  std::multiset<std::int64_t> resolved_clutter;
  for (std::int64_t id : clutter_ids) resolved_clutter.insert(dc.resolve({id})[0]);
  EXPECT_GT(clutter_ids.size(), 20u);
  ASSERT_GE(close_steps.size(), 3u);
  std::set<std::size_t> first_of_node, last_of_node;  // local map indices
  std::size_t leaf = 0;
  for (const auto& [leaves, features] : dc.stack_shape()) {
    first_of_node.insert(leaf);
    leaf += static_cast<std::size_t>(leaves);
    last_of_node.insert(leaf - 1);
  }
  const auto window = static_cast<std::size_t>(config.tentative_window);
  // Local map j holds steps (close_steps[j-1], close_steps[j]]; the first one starts at -1.
  const auto begin_of = [&](std::size_t j) { return j == 0 ? -1.0 : static_cast<double>(close_steps[j - 1]); };
  int dropped = 0;
  for (std::int64_t id : clutter_ids) {
    const std::int64_t resolved = dc.resolve({id})[0];
    if (resolved == -1) {
      ++dropped;
      continue;
    }
    if (in_local_map.count(id) != 0 || resolved_clutter.count(resolved) >= 2) continue;
    const std::size_t step = clutter_step.at(id);
    const std::size_t j = static_cast<std::size_t>(
        std::lower_bound(close_steps.begin(), close_steps.end(), step) - close_steps.begin());
    const bool awaits_previous = j > 0 && first_of_node.count(j) != 0 &&
                                 static_cast<double>(step) <= begin_of(j) + static_cast<double>(window);
    const bool awaits_next = last_of_node.count(j) != 0 && close_steps[j] - step <= window;
    EXPECT_TRUE(awaits_previous || awaits_next) << id << " started at step " << step;
  }
  EXPECT_GT(dropped, static_cast<int>(clutter_ids.size()) / 2);
}

}  // namespace
}  // namespace dcslam
