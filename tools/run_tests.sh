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
# One worker a core, at most four (a worker holds a test module's data, Victoria Park's among
# them); a module's tests stay on one worker, so module-scoped fixtures are built once.
workers=$(nproc 2>/dev/null || echo 2)
if (( workers > 4 )); then workers=4; fi
"$PY" -m pytest -q -n "$workers" --dist loadfile tests/python
