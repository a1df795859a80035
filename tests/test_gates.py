"""The code gates, run with the tests: ruff's rules (pyproject.toml, [tool.ruff.lint]) over the package, the
tests and the tools, and mypy (pyproject.toml, [tool.mypy]) over the package. Each test fails with the
tool's own report."""

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=REPO, capture_output=True, text=True, timeout=900,
                          check=False)


def test_ruff_finds_nothing():
    res = _run("ruff", "check", "--no-cache", "semmap", "tests", "tools")
    assert res.returncode == 0, res.stdout + res.stderr


def test_mypy_finds_nothing():
    res = _run("mypy")
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Success: no issues found" in res.stdout
