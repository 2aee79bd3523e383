#!/usr/bin/env bash
# Builds the C++ tests with sanitizers and runs them:
#   address  AddressSanitizer + UndefinedBehaviorSanitizer (build/asan), the whole suite;
#   thread   ThreadSanitizer (build/tsan), the tests that run joins on the worker thread
#            (threaded_joins) or compare the join schedules: TSan slows everything 10-50x,
#            and the rest of the suite is single-threaded. They are all in test_dc_slam.cpp,
#            built alone as dcslam_thread_tests, so that this build compiles no other test.
# Any report fails the run (halt_on_error). CI runs the thread part (tools/run_tests.sh).
#
# Usage: bash tools/run_sanitizers.sh [address|thread|all]   (default: all)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# The cases that run DCSlam with threaded_joins, by name (tests/cpp/test_dc_slam.cpp names each
# case by its parameters: --gtest_list_tests shows them), and the two that check the three
# schedules agree bit for bit, and estimate() (its fold, its joins' fill, the re-linearisation
# pass) on several threads: about 2 min under TSan.
THREAD_TESTS='DcSlam.ImmediateAmortizedAndThreadedAreBitwiseIdentical:DcSlam.PastPosesAreBitwiseTheSameInEveryJoinMode'
THREAD_TESTS+=':DcSlam.AFailedJoinRollsBackInEveryMode:DcSlam.WeakJoinsDecideAlikeInEveryMode'
THREAD_TESTS+=':LocalMapSizes/DcSlamLinear.EqualsEkfExactly/features4_threaded'
THREAD_TESTS+=':LocalMapSizes/DcSlamLinear.EqualsEkfExactly/features25_threaded'
THREAD_TESTS+=':Modes/DcSlamAnytime.*/threaded'
THREAD_TESTS+=':LocalMapSizes/DcSlamPastPoses.*/features4_threaded:LocalMapSizes/DcSlamPastPoses.*/features25_threaded'
THREAD_TESTS+=':DcSlamOnlineLocalisation.*:RunTasks.*:DcSlam.EstimateIsBitwiseTheSameOnAnyNumberOfThreads'
THREAD_TESTS+=':DcSlamTree.OnePassIsBitwiseTheSameOnAnyNumberOfThreads:MapJoining.FilledOnSeveralThreadsGivesBitwiseTheSameResult'

which="${1:-all}"
case "$which" in
  address|thread|all) ;;
  *) echo "run_sanitizers: expected address, thread or all, got '$which'" >&2; exit 2 ;;
esac

# -O1 -g1: line tables are all a report's stack needs. Against RelWithDebInfo's -O2 -g the TSan
# build compiles in 197 s of CPU instead of 367, and its tests run no longer (133 s against 148 s).
build() {  # build <dir> <sanitizer> <target>
  cmake -S . -B "$1" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1 -DNDEBUG" \
    -DDCSLAM_SANITIZE="$2" \
    -DDCSLAM_BUILD_TESTS=ON -DDCSLAM_BUILD_BENCH=OFF -DDCSLAM_WERROR=ON >/dev/null
  cmake --build "$1" --target "$3" -j 2
}

if [[ "$which" == address || "$which" == all ]]; then
  echo "== ASan + UBSan: build/asan"
  build build/asan address dcslam_tests
  ASAN_OPTIONS=halt_on_error=1:detect_leaks=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
    build/asan/tests/cpp/dcslam_tests --gtest_brief=1
fi
if [[ "$which" == thread || "$which" == all ]]; then
  echo "== TSan: build/tsan ($THREAD_TESTS)"
  build build/tsan thread dcslam_thread_tests
  # Each pattern must select a test: a renamed case would otherwise drop out silently.
  IFS=: read -ra patterns <<<"$THREAD_TESTS"
  for pattern in "${patterns[@]}"; do
    if ! build/tsan/tests/cpp/dcslam_thread_tests --gtest_list_tests --gtest_filter="$pattern" | grep -q '^  '; then
      echo "run_sanitizers: no test is named '$pattern' (tests/cpp/test_dc_slam.cpp, test_map_joining.cpp)" >&2
      exit 1
    fi
  done
  TSAN_OPTIONS=halt_on_error=1:second_deadlock_stack=1 \
    build/tsan/tests/cpp/dcslam_thread_tests --gtest_brief=1 --gtest_filter="$THREAD_TESTS"
fi
