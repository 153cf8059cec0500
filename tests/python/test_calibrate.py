"""slshadow.calibrate_* against `slshadow calibrate ...` on the same real data (../shared/data, as
tests/apps/cmd_calibrate_test.cc uses it): OpenCV's stereo chessboard sample (camera, stereo, and
the corners detected in Python calibrated by calibrate_corners) and kamino's five fringe captures
of a board (projector from folders, rig from ImageSets written in Python). The oracle is the
command's own rig file and report on the same inputs."""

import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import slshadow as sl
from conftest import SOURCE_DIR, cli_error, run_cli

DATA = Path(os.environ.get("SLSHADOW_SHARED_DATA_DIR", SOURCE_DIR.parent / "shared" / "data"))
TARGET = SOURCE_DIR / "config" / "targets" / "opencv-stereo-chessboard.yaml"
KAMINO = DATA / "kamino-procam-graycode"
KAMINO_TARGET = SOURCE_DIR / "config" / "targets" / "kamino-procam-graycode.yaml"
KAMINO_PATTERNS = SOURCE_DIR / "config" / "patterns" / "kamino_opencv_graycode.yaml"
# Ceres sums in threads in varying order: two runs of the command itself differ by a few 1e-6 in
# the cross-validation refits (3.0e-6 seen in centre_px), so figures are compared to 1e-5.
RTOL = 1e-5


def strip_times(x):
    """Without times and Ceres' termination text (its last cost change differs between runs)."""
    if isinstance(x, dict):
        return {k: strip_times(v) for k, v in x.items()
                if not (k.endswith("_s") or k in ("created_utc", "created", "termination"))}
    if isinstance(x, list):
        return [strip_times(v) for v in x]
    return x


def assert_close(ours, theirs, path="", rtol=RTOL, atol=1e-9):
    """Trees equal, numbers to rtol / atol."""
    assert type(ours) == type(theirs) or {type(ours), type(theirs)} <= {int, float}, path
    if isinstance(ours, dict):
        assert set(ours) == set(theirs), f"{path}: {set(ours) ^ set(theirs)}"
        for k in ours:
            assert_close(ours[k], theirs[k], f"{path}.{k}", rtol, atol)
    elif isinstance(ours, list):
        assert len(ours) == len(theirs), path
        for i, (a, b) in enumerate(zip(ours, theirs)):
            assert_close(a, b, f"{path}[{i}]", rtol, atol)
    elif isinstance(ours, (int, float)) and not isinstance(ours, bool):
        assert abs(ours - theirs) <= atol + rtol * abs(theirs), f"{path}: {ours} != {theirs}"
    else:
        assert ours == theirs, path


def assert_same_calibration(result, cli_out, call):
    """The module's rig and report folder against the command's (out = <dir>/rig.yaml)."""
    cli_rig = sl.Rig.load(cli_out)
    ours_rig = strip_times(result["rig"].to_dict())
    assert_close(ours_rig, strip_times(cli_rig.to_dict()))
    assert result["calibration"] == result["rig"].to_dict()["calibration"]
    cli_report = cli_out.parent / (cli_out.stem + "_report")
    for name in sorted(os.listdir(cli_report)):
        if not name.endswith(".json"):
            continue
        ours = json.loads((Path(result["report_dir"]) / name).read_text())
        theirs = json.loads((cli_report / name).read_text())
        assert ours.get("extra", {}).pop("command", "") == f"slshadow.{call} (Python)"
        theirs.get("extra", {}).pop("command", None)
        assert_close(strip_times(ours), strip_times(theirs), name)
        if name == "summary.json":
            summary = dict(result["summary"])
            summary.get("extra", {}).pop("command", None)
            assert_close(strip_times(summary), strip_times(theirs), "summary")
    for device in cli_rig.cameras + ([cli_rig.projector] if cli_rig.projector else []):
        np.testing.assert_allclose(result["rig"].device(device.name).model.params,
                                   device.model.params, rtol=RTOL)


def left_images():
    images = sorted((DATA / "opencv-stereo-chessboard").glob("left*.jpg"))
    assert len(images) >= 10, f"the board images are missing from {DATA}"
    return images


@pytest.fixture(scope="module")
def cli_camera(tmp_path_factory):
    """`slshadow calibrate camera` on the left images (the oracle of two tests)."""
    out = tmp_path_factory.mktemp("cli_camera") / "rig.yaml"
    proc = run_cli("calibrate", "camera", "--images", *left_images(), "--target", TARGET, "--out",
                   out, "--camera-name", "left")
    return out, proc.stdout


def monotone_runs(calls):
    """The (stage, done, total) calls cut into runs of one stage; asserts done/total rises within
    each run and stays in [0, 1]. Returns [(stage, number of calls, last done, total)]."""
    runs = []
    for stage, done, total in calls:
        assert 0 <= done <= total, (stage, done, total)
        if runs and runs[-1][0] == stage and done >= runs[-1][2]:
            assert total == runs[-1][3]
            runs[-1] = (stage, runs[-1][1] + 1, done, total)
        else:
            runs.append((stage, 1, done, total))
    return runs


def test_calibrate_camera_matches_cli(cli_camera, tmp_path):
    cli_out, cli_stdout = cli_camera
    images = left_images()
    calls = []
    result = sl.calibrate_camera(images, TARGET, tmp_path / "rig.yaml", camera="left",
                                 progress=lambda *a: calls.append(a))
    # One call per image read, then around the solve.
    assert monotone_runs(calls) == [("detect", len(images), len(images), len(images)),
                                    ("calibrate", 2, 1, 1)]
    assert_same_calibration(result, cli_out, "calibrate_camera")
    model = result["rig"].camera("left").model
    assert model.width == 640 and 400 < model.params[0] < 700
    assert result["log"] and result["log"].splitlines()[0] in cli_stdout


def test_calibrate_corners_matches_cli_camera(cli_camera, tmp_path):
    """The corners found by detect_target, calibrated from arrays, give the command's camera."""
    cli_out, _ = cli_camera
    object_points, image_points, labels = [], [], []
    for path in left_images():
        det = sl.detect_target(path, TARGET)
        assert det["found"] and det["image_points"].shape == (54, 2)
        assert det["object_points"].shape == (54, 3) and det["width"] == 640
        # An array in gives the file's detection.
        array = np.asarray(Image.open(path).convert("L"))
        np.testing.assert_array_equal(sl.detect_target(array, TARGET)["image_points"],
                                      det["image_points"])
        object_points.append(det["object_points"])
        image_points.append(det["image_points"])
        labels.append(path.name)
    result = sl.calibrate_corners(object_points, image_points, (640, 480), tmp_path / "rig.yaml",
                                  camera="left", labels=labels)
    cli_rig = sl.Rig.load(cli_out)
    # The rig file (its evidence: observations, options, summary) is the command's.
    assert_close(strip_times(result["rig"].to_dict()), strip_times(cli_rig.to_dict()))
    np.testing.assert_allclose(result["rig"].camera("left").model.params,
                               cli_rig.camera("left").model.params, rtol=RTOL)
    # A dict per camera with a pose not seen (None) is accepted; mismatched counts are refused.
    two = sl.calibrate_corners(object_points, {"a": image_points, "b": [None] + image_points[1:]},
                               {"a": (640, 480), "b": (640, 480)}, tmp_path / "two.yaml",
                               cross_validate=False)
    assert two["rig"].camera_names == ["a", "b"]
    assert "not found: pose_0: not given" in two["log"]
    with pytest.raises(sl.Error, match=r"image_points\['camera'\]\[0\]: 54 image points but "
                                       r"object_points\[0\] has 53"):
        sl.calibrate_corners([p[:53] for p in object_points], image_points, (640, 480),
                             tmp_path / "bad.yaml")
    assert not (tmp_path / "bad.yaml").exists()


def test_calibrate_stereo_matches_cli(tmp_path):
    """The pairs and --fix-aspect of tests/apps/cmd_calibrate_test.cc's stereo test."""
    ids = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
    left = [DATA / "opencv-stereo-chessboard" / f"left{i:02d}.jpg" for i in ids]
    right = [DATA / "opencv-stereo-chessboard" / f"right{i:02d}.jpg" for i in ids]
    cli_out = tmp_path / "cli" / "rig.yaml"
    run_cli("calibrate", "stereo", "--target", TARGET, "--fix-aspect", "--out", cli_out,
            "--opencv-out", tmp_path / "cli" / "stereo.yml", "--left", *left, "--right", *right)
    calls = []
    result = sl.calibrate_stereo(left, right, TARGET, tmp_path / "py" / "rig.yaml",
                                 fix_aspect=True, opencv_out=tmp_path / "py" / "stereo.yml",
                                 progress=lambda *a: calls.append(a))
    assert monotone_runs(calls) == [("detect", 13, 13, 13), ("detect", 13, 13, 13),
                                    ("calibrate", 2, 1, 1)]
    assert_same_calibration(result, cli_out, "calibrate_stereo")
    assert result["rig"].camera_names == ["left", "right"]
    assert (tmp_path / "py" / "stereo.yml").exists()
    # A bad option: the command's message, word for word.
    with pytest.raises(sl.Error) as e:
        sl.calibrate_stereo(left, right[:3], TARGET, tmp_path / "bad.yaml")
    assert str(e.value) == cli_error("calibrate", "stereo", "--target", TARGET, "--out",
                                     tmp_path / "bad.yaml", "--left", *left, "--right", *right[:3])
    with pytest.raises(sl.Error) as e:
        sl.calibrate_camera(left, TARGET, tmp_path / "bad.yaml", loss="l1")
    assert str(e.value) == cli_error("calibrate", "camera", "--target", TARGET, "--out",
                                     tmp_path / "bad.yaml", "--images", *left, "--loss", "l1")
    assert not (tmp_path / "bad.yaml").exists()


# The decoding and model options of tests/apps/cmd_calibrate_test.cc's kamino tests.
KAMINO_CLI = ["--target", KAMINO_TARGET, "--shadow-threshold", "40", "--contrast-threshold", "5",
              "--min-views", "5", "--no-cross-validation", "--principal-point-inside"]
KAMINO_PY = dict(shadow_threshold=40, contrast_threshold=5, min_views=5, cross_validate=False,
                 principal_point_inside=True)


def test_calibrate_projector_matches_cli(tmp_path):
    captures = [KAMINO / f"capture_{p}" for p in range(5)]
    cli_out = tmp_path / "cli" / "procam.yaml"
    run_cli("calibrate", "projector", "--patterns", KAMINO_PATTERNS, *KAMINO_CLI, "--out", cli_out,
            "--captures", *captures)
    calls = []
    result = sl.calibrate_projector(captures, KAMINO_PATTERNS, KAMINO_TARGET,
                                    tmp_path / "py" / "procam.yaml",
                                    progress=lambda *a: calls.append(a), **KAMINO_PY)
    assert monotone_runs(calls) == [("decode", 5, 5, 5), ("calibrate", 2, 1, 1)]
    assert_same_calibration(result, cli_out, "calibrate_projector")
    assert result["rig"].projector is not None
    assert result["calibration"]["summary"]["devices"][1]["rms_px"] <= 0.43


@pytest.fixture(scope="module")
def kamino_sets(tmp_path_factory):
    """kamino's captures as ImageSets written through write_image_set (arrays from PIL), with the
    rig `slshadow calibrate import` makes of upstream's calibration; the module's import of the
    same file gives the same rig, and its export the command's file byte for byte."""
    tmp = tmp_path_factory.mktemp("kamino")
    xml = KAMINO / "calibration_result_ccf1cd8.xml"
    nominal = tmp / "nominal.yaml"
    run_cli("calibrate", "import", xml, "--out", nominal, "--projector-size", "1024x768")
    rig = sl.calibrate_import(xml, tmp / "py_nominal.yaml", projector_size=(1024, 768))
    assert rig.to_dict() == sl.Rig.load(nominal).to_dict()
    assert (tmp / "py_nominal.yaml").read_text() == nominal.read_text()
    run_cli("calibrate", "export", nominal, "--out", tmp / "cli.yml")
    sl.calibrate_export(rig, tmp / "py.yml")
    assert (tmp / "py.yml").read_bytes() == (tmp / "cli.yml").read_bytes()
    with pytest.raises(sl.Error) as e:
        sl.calibrate_import(tmp / "none.yml")
    assert str(e.value) == cli_error("calibrate", "import", tmp / "none.yml", "--out",
                                     tmp / "x.yaml")
    patterns = sl.PatternSpec.load(KAMINO_PATTERNS)
    sets = []
    for p in range(5):
        frames = np.stack([np.asarray(Image.open(KAMINO / f"capture_{p}" / f"graycode_{i:02d}.png")
                                      .convert("L")) for i in range(patterns.num_images)])
        sets.append(sl.write_image_set(tmp / f"pose{p}", rig, patterns, {"camera": frames},
                                       encoding="pgm", source="replay"))
    return nominal, sets


def test_calibrate_rig_from_imagesets_written_in_python_matches_cli(kamino_sets, tmp_path):
    _, sets = kamino_sets
    cli_out = tmp_path / "cli" / "rig.yaml"
    run_cli("calibrate", "rig", *KAMINO_CLI, "--out", cli_out, "--imagesets",
            *[s.dir for s in sets])
    calls = []
    result = sl.calibrate_rig(sets, KAMINO_TARGET, tmp_path / "py" / "rig.yaml",
                              progress=lambda *a: calls.append(a), **KAMINO_PY)
    assert monotone_runs(calls) == [("decode", 5, 5, 5), ("calibrate", 2, 1, 1)]
    assert_same_calibration(result, cli_out, "calibrate_rig")
    assert result["calibration"]["summary"]["bounds_active"] == ["projector cy = 767.5 (upper bound)"]


def test_calibrate_refine_matches_cli(kamino_sets, tmp_path):
    """`calibrate refine` of upstream's calibration against the first capture (as
    tests/apps/cmd_calibrate_test.cc does)."""
    nominal, sets = kamino_sets
    run_cli("calibrate", "refine", "--rig", nominal, "--imageset", sets[0].dir, "--out",
            tmp_path / "cli.yaml")
    result = sl.calibrate_refine(nominal, sets[0], tmp_path / "py.yaml")
    cli_rig = sl.Rig.load(tmp_path / "cli.yaml")
    assert_close(strip_times(result["rig"].to_dict()), strip_times(cli_rig.to_dict()))
    refine = cli_rig.to_dict()["calibration"]["refine"]
    assert result["after"]["median_px"] <= result["before"]["median_px"] + 1e-9
    assert abs(result["before"]["median_px"] - refine["before_median_px"]) <= 1e-9
    assert result["message"]
    with pytest.raises(sl.Error) as e:
        sl.calibrate_refine(nominal, tmp_path / "missing", tmp_path / "x.yaml")
    assert str(e.value) == cli_error("calibrate", "refine", "--rig", nominal, "--imageset",
                                     tmp_path / "missing", "--out", tmp_path / "x.yaml")
    assert not (tmp_path / "x.yaml").exists()
