"""Each Python call against the command line's own output on the same inputs: the same images as
`slshadow simulate`, the same cloud bit for bit as `slshadow reconstruct`, the same figures as
`slshadow compare`, the same text as `slshadow rig show`, the same images as `slshadow patterns
generate`."""

import json

import numpy as np
import pytest
from PIL import Image

import slshadow as sl
from conftest import DEMO_PATTERNS, DEMO_SCENE, QUARTER_RIG, run_cli
from plyfile_oracle import read_vertices


def assert_cloud_equals_ply(cloud, ply_path):
    ply = read_vertices(ply_path)
    points = np.column_stack([ply["x"], ply["y"], ply["z"]])
    assert points.dtype == np.float64
    assert len(cloud) == len(points) > 1000
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.normals, np.column_stack([ply["nx"], ply["ny"], ply["nz"]]))
    for name in cloud.scalar_names:
        np.testing.assert_array_equal(cloud.scalar(name), ply[name], err_msg=name)
    assert set(cloud.scalar_names) == set(ply) - {"x", "y", "z", "nx", "ny", "nz"}


def test_simulate_matches_cli_images(cli_scan):
    scan = sl.simulate(sl.Rig.load(QUARTER_RIG), sl.Scene.load(DEMO_SCENE),
                       sl.PatternSpec.load(DEMO_PATTERNS))
    written = sl.ImageSet.open(cli_scan)
    assert scan.cameras == written.cameras == ["left", "right"]
    for camera in scan.cameras:
        ours = scan.images(camera)
        assert ours.shape == (38, 300, 480) and ours.dtype == np.uint8
        np.testing.assert_array_equal(ours, written.images(camera))


# (command-line flags, keyword arguments): every mode and every triangulation method.
RECONSTRUCTIONS = [
    ([], {}),
    (["--mode", "projector", "--method", "dlt"], {"mode": "projector", "method": "dlt"}),
    (["--mode", "stereo", "--method", "optimal"], {"mode": "stereo", "method": "optimal"}),
    (["--mode", "projector", "--method", "optimal"], {"mode": "projector", "method": "optimal"}),
    (["--mode", "stereo", "--method", "dlt"], {"mode": "stereo", "method": "dlt"}),
    (["--mode", "stereo", "--method", "midpoint", "--stereo-interpolation", "cubic",
      "--no-outlier-filter", "--min-depth-mm", "300"],
     {"mode": "stereo", "method": "midpoint", "stereo_interpolation": "cubic",
      "filter_outliers": False, "min_depth_mm": 300}),
]


@pytest.mark.parametrize("flags,kwargs", RECONSTRUCTIONS)
def test_reconstruct_matches_cli_bit_for_bit(cli_scan, tmp_path, flags, kwargs):
    cli_ply = tmp_path / "cli.ply"
    run_cli("reconstruct", cli_scan, "--out", cli_ply, "--quiet", *flags)
    rec = sl.reconstruct(sl.ImageSet.open(cli_scan), **kwargs)
    assert_cloud_equals_ply(rec.cloud, cli_ply)
    source = rec.source_pixel
    np.testing.assert_array_equal(source[:, 0], rec.cloud.scalar("u"))
    np.testing.assert_array_equal(source[:, 1], rec.cloud.scalar("v"))
    # The summary's counts are the command line's.
    cli_summary = json.loads((tmp_path / "cli.summary.json").read_text())
    for ours, theirs in zip(rec.summaries, cli_summary["reconstructions"]):
        for key in ("camera", "other_device", "cells", "points", "rejected", "mode", "method"):
            assert ours[key] == theirs[key], key
    # Written by Python: the same files.
    py_ply = tmp_path / "py.ply"
    rec.write(py_ply)
    assert py_ply.read_bytes() == cli_ply.read_bytes()


def test_reconstruct_in_memory_scan_matches_cli(cli_scan, tmp_path):
    cli_ply = tmp_path / "cli.ply"
    run_cli("reconstruct", cli_scan, "--out", cli_ply, "--quiet", "--mode", "stereo")
    scan = sl.simulate(sl.Rig.load(QUARTER_RIG), sl.Scene.load(DEMO_SCENE), DEMO_PATTERNS)
    assert_cloud_equals_ply(sl.reconstruct(scan, mode="stereo").cloud, cli_ply)
    # The same images as a dict of arrays with rig= and patterns=.
    images = {camera: scan.images(camera) for camera in scan.cameras}
    rec = sl.reconstruct(images, scan.patterns, rig=scan.rig, mode="stereo")
    assert_cloud_equals_ply(rec.cloud, cli_ply)


def test_compare_matches_cli_figures(cli_scan, tmp_path):
    cli_ply = tmp_path / "cloud.ply"
    run_cli("reconstruct", cli_scan, "--out", cli_ply, "--quiet")
    reference = cli_scan / "ground_truth" / "left" / "surface.ply"
    report_dir = tmp_path / "report"
    run_cli("compare", cli_ply, reference, "--out", report_dir, "--threshold-mm", "0.1",
            "--register", "icp")
    cli = json.loads((report_dir / "report.json").read_text())
    result = sl.compare(str(cli_ply), str(reference), threshold_mm=0.1, registration="icp")
    ours = result.figures

    def strip(report):
        report = json.loads(json.dumps(report))
        report.pop("created_utc", None)
        report["registration"].pop("time_s", None)
        report.pop("time_s", None)
        return report

    assert strip(ours) == strip(cli)
    assert ours["c2c"]["count"] == len(result.deviations) > 1000
    compared = read_vertices(report_dir / "compared.ply")
    np.testing.assert_array_equal(result.deviations.astype(np.float32), compared["deviation"])
    np.testing.assert_array_equal(result.reference_from_cloud,
                                  np.array(cli["registration"]["transform"]))
    # The report folder written by Python holds the same report.
    py_dir = tmp_path / "py_report"
    again = sl.compare(sl.read_ply(cli_ply), sl.Reference.load(reference), out=py_dir,
                       cloud_source=str(cli_ply), threshold_mm=0.1, registration="icp")
    assert strip(json.loads((py_dir / "report.json").read_text())) == strip(cli)
    assert strip(again.figures) == strip(cli)


def test_rig_describe_matches_rig_show():
    assert sl.Rig.load(QUARTER_RIG).describe() == run_cli("rig", "show", QUARTER_RIG).stdout


def test_pattern_images_and_frames_match_patterns_generate(tmp_path):
    out = tmp_path / "patterns"
    run_cli("patterns", "generate", DEMO_PATTERNS, "--out", out)
    spec = sl.PatternSpec.load(DEMO_PATTERNS)
    images = spec.generate()
    frames = json.loads((out / "frames.json").read_text())
    assert images.shape == (spec.num_images, 800, 1280) == (38, 800, 1280)
    assert [f["frame"] for f in frames] == spec.frame_names == [f["name"] for f in spec.frames]
    for i, frame in enumerate(frames):
        np.testing.assert_array_equal(images[i], np.asarray(Image.open(out / frame["file"])))
    roles = [f["role"] for f in spec.frames]
    assert roles.count("phase") == 8 and roles.count("gray_bit") == roles.count("gray_bit_inverse")
    assert json.loads((out / "patterns.json").read_text()) == spec.to_dict()


def test_decode_against_simulated_ground_truth(cli_scan):
    image_set = sl.ImageSet.open(cli_scan)
    spec = image_set.patterns
    decoded = sl.decode(image_set.images("left"), spec)
    truth_x = np.load(cli_scan / "ground_truth" / "left" / "proj_x.npy")
    truth_y = np.load(cli_scan / "ground_truth" / "left" / "proj_y.npy")
    valid = decoded.mask & np.isfinite(truth_x)
    assert valid.sum() > 0.3 * valid.size
    assert np.all(np.isnan(decoded.proj_x[~decoded.mask]))
    err = np.hypot(decoded.proj_x[valid] - truth_x[valid], decoded.proj_y[valid] - truth_y[valid])
    assert np.median(err) < 0.05 and np.percentile(err, 95) < 0.5
    counts = decoded.counts()
    assert counts["valid"] == decoded.mask.sum() and sum(counts.values()) == decoded.mask.size
    assert decoded.modulation.dtype == np.float32 and np.all(decoded.modulation[decoded.mask] > 0)
    # The decoder's thresholds are keyword options, validated by the C++ reader.
    strict = sl.decode(image_set.images("left"), spec, shadow_threshold=200)
    assert strict.mask.sum() < decoded.mask.sum()
