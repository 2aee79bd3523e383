import subprocess
import sys

import dcslam


def run(*args):
    return subprocess.run([sys.executable, "-m", "dcslam", *args], capture_output=True, text=True, timeout=120)


def test_version_and_help():
    out = run("--version")
    assert out.returncode == 0 and dcslam.__version__ in out.stdout
    out = run("--help")
    assert out.returncode == 0 and "selfcheck" in out.stdout


def test_selfcheck_passes():
    out = run("selfcheck", "--samples", "20")
    assert out.returncode == 0, out.stdout + out.stderr
    assert "compose" in out.stdout and "FAIL" not in out.stdout
