"""Fixtures of the slshadow pytest suite: the slshadow binary, the checkout's configs, and one
virtual scan written by the command line (the quarter-resolution demo rig over the demo part),
shared by the tests that compare a Python call with the command line's own output.

A skipped test fails the session: every test here must run on a prepared machine."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

SOURCE_DIR = Path(os.environ.get("SLSHADOW_SOURCE_DIR", Path(__file__).resolve().parents[2])).resolve()
SLSHADOW_BIN = os.environ.get("SLSHADOW_BIN", str(SOURCE_DIR / "build" / "apps" / "slshadow"))
QUARTER_RIG = SOURCE_DIR / "config" / "studies" / "quarter_demo_rig.yaml"
DEMO_SCENE = SOURCE_DIR / "config" / "demo" / "scene.yaml"
DEMO_PATTERNS = SOURCE_DIR / "config" / "demo" / "patterns.yaml"

_skipped = []


def run_cli(*args, check=True):
    """Runs the slshadow binary; returns the CompletedProcess (text)."""
    proc = subprocess.run([SLSHADOW_BIN, *map(str, args)], capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise AssertionError(f"slshadow {' '.join(map(str, args))} failed:\n{proc.stderr}")
    return proc


def cli_error(*args):
    """The one-line message the command line prints for a failing command (without the
    'slshadow: error: ' prefix); asserts it failed."""
    proc = run_cli(*args, check=False)
    assert proc.returncode != 0, f"slshadow {args} succeeded"
    lines = [l for l in proc.stderr.splitlines() if l.startswith("slshadow: error: ")]
    assert len(lines) == 1, proc.stderr
    return lines[0][len("slshadow: error: "):]


@pytest.fixture(scope="session")
def tmp_root(tmp_path_factory):
    """A session folder under SLSHADOW_TEST_TMP (removed at the end), else pytest's own."""
    base = os.environ.get("SLSHADOW_TEST_TMP")
    if not base:
        yield tmp_path_factory.mktemp("slshadow")
        return
    import shutil
    import tempfile

    Path(base).mkdir(parents=True, exist_ok=True)
    root = Path(tempfile.mkdtemp(prefix="pytest-", dir=base))
    yield root
    shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(scope="session")
def cli_scan(tmp_root):
    """The command line's virtual scan (with ground truth) of the demo part by the quarter rig."""
    out = tmp_root / "cli_scan"
    run_cli("simulate", "--rig", QUARTER_RIG, "--scene", DEMO_SCENE, "--patterns", DEMO_PATTERNS,
            "--out", out, "--encoding", "pgm", "--quiet")
    return out


def pytest_runtest_logreport(report):
    if report.skipped:
        _skipped.append(report.nodeid)


def pytest_sessionfinish(session, exitstatus):
    if _skipped:
        sys.stderr.write("slshadow pytest: skipped tests fail the suite: %s\n" % ", ".join(_skipped))
        session.exitstatus = 1
