"""docs/python.md's worked script runs as written (simulate -> reconstruct -> compare -> a
matplotlib figure -> Open3D) and produces what it says."""

import os
import re
import subprocess
import sys

import numpy as np
from PIL import Image

from conftest import SOURCE_DIR
from plyfile_oracle import read_vertices


def worked_script():
    text = (SOURCE_DIR / "docs" / "python.md").read_text()
    match = re.search(r"<!-- worked-script -->\n```python\n(.*?)```", text, re.S)
    assert match, "docs/python.md has no worked script"
    return match.group(1)


def test_worked_script_runs(tmp_path):
    script = tmp_path / "worked.py"
    script.write_text(worked_script())
    env = dict(os.environ, SLSHADOW_CONFIG=str(SOURCE_DIR / "config"))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "RMS" in proc.stdout
    rms = float(re.search(r"RMS ([0-9.]+) mm", proc.stdout).group(1))
    assert 0 < rms < 0.05  # a noise-free simulated scan of the demo part
    figure = np.asarray(Image.open(tmp_path / "deviations.png"))
    assert figure.shape[0] == 400 and figure.shape[1] == 1100
    cloud = read_vertices(tmp_path / "cloud_2mm.ply")
    assert len(cloud["x"]) > 100
