#!/usr/bin/env bash
# Runs the benchmarks recorded in BENCHMARKS.md; outputs (text and JSON) go to results/bench/.
# Usage: bash benchmarks/run_all.sh [path/to/dcslam_bench]   (after tools/setup.sh; ~8 min)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
bench=${1:-build/dev/benchmarks/dcslam_bench}
out=results/bench
mkdir -p "$out"
run() {  # name, arguments...
  local name=$1; shift
  echo "== dcslam_bench $*" | tee "$out/$name.txt"
  "$bench" "$@" --json "$out/$name.json" | tee -a "$out/$name.txt"
}
# EKF per-step cost up to 2,000+ features on the snail (issue 3).
run ekf_snail sim --trajectory snail --steps 1150 --filter ekf
run ekf_snail_large sim --trajectory snail --steps 2200 --filter ekf
# EKF against D&C, known association, each trajectory at ~2,000 features (issue 5).
for t in straight loop lawn_mowing snail; do
  steps=600; [[ $t == lawn_mowing || $t == snail ]] && steps=1150
  run "both_$t" sim --trajectory "$t" --steps "$steps" --filter both
done
# Fitted exponents of total time against n.
run scaling_loop_both scaling --trajectory loop --sizes 150,300,600 --filter both
run scaling_loop_dc scaling --trajectory loop --sizes 300,600,1200,2400 --filter dc
# Data association with clutter, unknown ids (issues 4 and 6).
for t in straight loop lawn_mowing snail; do
  run "assoc_$t" sim --trajectory "$t" --steps 600 --association jcbb --clutter 0.1 --filter both
done
run assoc_nn_loop sim --trajectory loop --steps 600 --association nn --clutter 0.1 --filter ekf
# The EKF's association cost per step as the map grows to ~5,000 features (~1 min).
run assoc_scaling_loop sim --trajectory loop --steps 1500 --association jcbb --clutter 0.1 --filter ekf
# Where NN fails: 3x the odometry noise.
for a in nn jcbb; do
  run "assoc_${a}_loop_noise3" sim --trajectory loop --steps 600 --association "$a" --clutter 0.1 \
    --odometry-noise-scale 3 --filter both
done
run association association
run ekf_association ekf-association
# Real data (issue 7).
run vp vp --filter both
run isam isam tests/data/isam_victoria_park.txt.gz --filter both
