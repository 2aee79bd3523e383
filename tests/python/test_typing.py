"""Typing: the checked-in stubs of the compiled module are what pybind11-stubgen makes of it,
and mypy passes on examples/ and on the README's Python examples."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STUBS = ROOT / "python" / "dcslam" / "_core"


def test_the_checked_in_stubs_match_the_compiled_module(tmp_path):
    subprocess.run([sys.executable, "-m", "pybind11_stubgen", "dcslam._core", "-o", str(tmp_path)],
                   check=True, capture_output=True, timeout=120)
    generated = tmp_path / "dcslam" / "_core"
    names = sorted(p.name for p in generated.glob("*.pyi"))
    assert names == sorted(p.name for p in STUBS.glob("*.pyi"))
    for name in names:
        assert (generated / name).read_text() == (STUBS / name).read_text(), (
            f"python/dcslam/_core/{name} is stale: regenerate with "
            f"'python -m pybind11_stubgen dcslam._core -o python' after building")


def test_mypy_passes_on_the_examples_and_the_readme(tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
    # One script, as a reader runs them: later blocks use the names of the first.
    assert len(blocks) >= 2 and "import dcslam" in blocks[0]
    (tmp_path / "readme.py").write_text("\n".join(blocks))
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(ROOT / "pyproject.toml"),
                          "--cache-dir", str(tmp_path / "cache"), str(ROOT / "examples"), str(tmp_path)],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr


def test_the_package_is_marked_typed():
    assert (ROOT / "python" / "dcslam" / "py.typed").exists()
