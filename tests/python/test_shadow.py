"""slshadow.shadow against `slshadow shadow` on the same scan: the same report (times aside) and
its maps as arrays equal to the PNG files the command writes."""

import json

import numpy as np
import pytest
from PIL import Image

import slshadow as sl
from conftest import DEMO_SCENE, cli_error, run_cli


def strip_times(x):
    if isinstance(x, dict):
        return {k: strip_times(v) for k, v in x.items()
                if not (k.endswith("_s") or k in ("stages", "seconds", "created_utc"))}
    if isinstance(x, list):
        return [strip_times(v) for v in x]
    return x


def test_shadow_matches_cli(cli_scan, tmp_path):
    cli_dir = tmp_path / "cli"
    run_cli("shadow", cli_scan, "--part", DEMO_SCENE, "--pose", 0, 0, 0, 0, 0, 0, "--out", cli_dir)
    cli = json.loads((cli_dir / "report.json").read_text())
    stages = []
    result = sl.shadow(sl.ImageSet.open(cli_scan), DEMO_SCENE, pose=[0, 0, 0, 0, 0, 0],
                       progress=lambda stage, done, total: stages.append(stage))
    # Around the run, and the steps of the twin's tracing and rendering within it.
    assert stages[0] == "shadow" and stages[-1] == "done"
    assert {"trace", "render"} <= set(stages)
    assert strip_times(result["report"]) == strip_times(cli)
    assert result["summary"].splitlines()[0] == (cli_dir / "summary.txt").read_text().splitlines()[0]
    w, x, y, z = cli["pose"]["rig_from_part"]["rotation_quat_wxyz"]
    rotation = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(result["rig_from_part"][:3, :3], rotation, atol=1e-12)
    np.testing.assert_array_equal(result["rig_from_part"][:3, 3],
                                  cli["pose"]["rig_from_part"]["translation_mm"])
    assert set(result["maps"]) == {"left", "right"}
    for camera, maps in result["maps"].items():
        entry = next(e for e in cli["maps"] if e["camera"] == camera)
        assert maps, camera
        for name, image in maps.items():
            np.testing.assert_array_equal(image, np.asarray(Image.open(cli_dir / entry[name])),
                                          err_msg=f"{camera} {name}")
    # Bad input: the command line's message, word for word.
    with pytest.raises(sl.Error) as e:
        sl.shadow(cli_scan, DEMO_SCENE, min_fitness=-1)
    assert str(e.value) == cli_error("shadow", cli_scan, "--part", DEMO_SCENE, "--min-fitness",
                                     "-1", "--out", tmp_path / "bad")
