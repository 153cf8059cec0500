"""The type stubs (python/slshadow/*.pyi) match the module: mypy's stubtest finds every runtime
name in the stubs and every stub name at run time (with the pybind11 facts of
stubtest_allowlist.txt), and the docstrings reach help()."""

import subprocess
import sys
from pathlib import Path

import slshadow as sl


def test_stubs_match_the_module():
    allowlist = Path(__file__).with_name("stubtest_allowlist.txt")
    proc = subprocess.run([sys.executable, "-m", "mypy.stubtest", "slshadow", "--allowlist",
                           str(allowlist)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout


def test_docstrings():
    assert "slshadow reconstruct" in sl.reconstruct.__doc__
    assert "GIL" in sl.reconstruct.__doc__ and "progress" in sl.simulate.__doc__
    assert "report.json" in sl.Comparison.figures.__doc__
    assert "no copy" in sl.PointCloud.__doc__
    stub = Path(sl.__file__).with_name("_slshadow.pyi")
    assert stub.exists() and Path(sl.__file__).with_name("py.typed").exists()
