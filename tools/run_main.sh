#!/usr/bin/env bash
# Installs whatever is missing, then runs the main job: EKF and D&C SLAM on Victoria Park,
# with outputs and plots in results/victoria_park/. Extra arguments go to `dcslam run
# victoria-park` (e.g. --max-steps 1000, --output DIR).
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
dcslam selfcheck
dcslam run victoria-park --filter both "$@"
