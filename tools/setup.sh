#!/usr/bin/env bash
# Installs whatever is missing to build, run and test dcslam, and nothing that is already
# there: Debian packages (compiler, Eigen, GoogleTest, zlib, venv), a virtual environment in
# .venv, and the package itself (editable, with its C++ tests and benchmark built in
# build/dev). Safe to run any number of times; rebuilds incrementally.
#
# Usage: source tools/setup.sh   (or bash tools/setup.sh)
set -euo pipefail

DCSLAM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$DCSLAM_ROOT"

debian_packages=(g++ make libeigen3-dev libgtest-dev zlib1g-dev python3-venv)
missing=()
for package in "${debian_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$package" 2>/dev/null | grep -q "install ok installed" ||
    missing+=("$package")
done
# python3-venv is only needed where python3 cannot make a venv by itself (Debian's python3).
if [[ " ${missing[*]} " == *" python3-venv "* ]] && python3 -c "import ensurepip" 2>/dev/null; then
  missing=("${missing[@]/python3-venv}")
fi
missing=($(printf '%s\n' "${missing[@]}" | grep -v '^$' || true))
if ((${#missing[@]})); then
  echo "setup: installing Debian packages: ${missing[*]}"
  sudo_cmd=()
  [[ $(id -u) -ne 0 ]] && sudo_cmd=(sudo)
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if [[ ! -x .venv/bin/python ]]; then
  echo "setup: creating .venv"
  python3 -m venv .venv
fi
PY="$DCSLAM_ROOT/.venv/bin/python"

# Build requirements go into the venv so the package builds without isolation, which keeps
# build/dev and makes rebuilds incremental.
# pybind11-stubgen is pinned: tests/python/test_typing.py compares its output with the checked-in
# stubs of the compiled module, byte for byte. joblib, dask[distributed] and threadpoolctl are
# dcslam.experiments' (the cluster extra).
if ! "$PY" -c "import scikit_build_core, pybind11, cmake, ninja, pytest, xdist, scipy, typer, rich, matplotlib, hypothesis, mypy, pybind11_stubgen, joblib, distributed, threadpoolctl" 2>/dev/null; then
  echo "setup: installing Python build and test requirements"
  "$PY" -m pip install -q --upgrade pip
  "$PY" -m pip install -q "scikit-build-core>=0.10" "pybind11>=2.12" cmake ninja \
    numpy "typer>=0.9" "rich>=13" "matplotlib>=3.6" pytest pytest-xdist scipy hypothesis mypy "pybind11-stubgen==3.0.0" \
    joblib "dask[distributed]" threadpoolctl
fi

# The development build is tuned for this machine and strict about warnings; the defaults
# (all three off) are for portable user builds. DCSLAM_LTO=OFF in the environment builds it
# without link-time optimisation, as CI does (.ci/run): the results are the same, and LTO
# generates the library's code again at the link of each of the three programs.
echo "setup: building dcslam (build/dev)"
"$PY" -m pip install -q --no-build-isolation --no-deps -e . \
  -Cbuild-dir=build/dev \
  -Ccmake.define.DCSLAM_BUILD_TESTS=ON \
  -Ccmake.define.DCSLAM_BUILD_BENCH=ON \
  -Ccmake.define.DCSLAM_NATIVE=ON \
  -Ccmake.define.DCSLAM_LTO="${DCSLAM_LTO:-ON}" \
  -Ccmake.define.DCSLAM_WERROR=ON
export PATH="$DCSLAM_ROOT/.venv/bin:$PATH"
