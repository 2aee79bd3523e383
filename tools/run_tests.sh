#!/usr/bin/env bash
# Installs whatever is missing, then runs every test: the C++ suite (ctest), its threaded
# tests under ThreadSanitizer and the Python suite (pytest). Exits non-zero on any failure.
set -euo pipefail
source "$(dirname "${BASH_SOURCE[0]}")/setup.sh"

echo "== ctest"
ctest --test-dir build/dev --output-on-failure -j2
# The worker thread's tests under ThreadSanitizer (a build of its own, build/tsan).
echo "== tsan"
bash tools/run_sanitizers.sh thread
echo "== pytest"
"$PY" -m pytest -q tests/python
