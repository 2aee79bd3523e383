"""A user's ``pip install .`` configures CMake with pyproject.toml's defines and nothing else:
its compile lines must hold no ``-march=native`` (a wheel that runs only on the machine that
built it), no ``-Werror`` (a newer compiler's new warning would break the install) and no
link-time optimisation. Checked on the compile commands of a real configure, which also shows
that asking for each option does put it there."""

import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pybind11
import pytest

ROOT = Path(__file__).resolve().parents[2]
DEVELOPER_FLAGS = ("-march=native", "-Werror", "-flto")


def pyproject_defines() -> list:
    settings = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["scikit-build"]
    defines = [f"-D{name}={value}" for name, value in settings["cmake"]["define"].items()]
    return defines + [f"-DCMAKE_BUILD_TYPE={settings['cmake']['build-type']}"]


def compile_lines(build: Path, *extra: str) -> list:
    cmake = shutil.which("cmake", path=str(Path(sys.executable).parent)) or shutil.which("cmake")
    if cmake is None:
        pytest.skip("no cmake")
    run = subprocess.run([cmake, "-S", str(ROOT), "-B", str(build), "-DCMAKE_EXPORT_COMPILE_COMMANDS=ON",
                          f"-Dpybind11_DIR={pybind11.get_cmake_dir()}", f"-DPython_EXECUTABLE={sys.executable}",
                          *pyproject_defines(), *extra],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    commands = json.loads((build / "compile_commands.json").read_text())
    assert commands
    return [entry["command"] for entry in commands]


def test_a_user_build_has_no_developer_flags(tmp_path):
    for line in compile_lines(tmp_path / "user"):
        assert not any(flag in line for flag in DEVELOPER_FLAGS), line


def test_the_developer_options_do_reach_the_compile_lines(tmp_path):
    lines = compile_lines(tmp_path / "developer", "-DDCSLAM_NATIVE=ON", "-DDCSLAM_WERROR=ON", "-DDCSLAM_LTO=ON")
    for flag in DEVELOPER_FLAGS:
        assert any(flag in line for line in lines), flag
