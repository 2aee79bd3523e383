#!/usr/bin/env bash
# Installs whatever is missing, then runs the main job.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"
dcslam selfcheck
