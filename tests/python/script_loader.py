"""Imports a benchmark script (benchmarks/), which is a file, not a package module, to test a
part of it that has no command line of its own (test_gtsam_compare.py: its GTSAM factor)."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def load_script(relative_path: str):
    """The module of ``ROOT / relative_path``, executed once per call."""
    path = ROOT / relative_path
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
