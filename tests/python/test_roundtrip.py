"""Round trips through the module: numpy -> ImageSet -> numpy, rig files, PLY files, and the
device models' project / unproject."""

import numpy as np
import pytest

import slshadow as sl
from conftest import DEMO_PATTERNS, QUARTER_RIG
from plyfile_oracle import read_vertices


@pytest.mark.parametrize("encoding", ["png", "pgm", "tiff"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_numpy_imageset_numpy(tmp_path, encoding, dtype):
    rig = sl.Rig.load(QUARTER_RIG)
    spec = sl.PatternSpec.load(DEMO_PATTERNS)
    rng = np.random.default_rng(34)
    high = np.iinfo(dtype).max
    images = {c: rng.integers(0, high, size=(spec.num_images, 300, 480), endpoint=True).astype(dtype)
              for c in rig.camera_names}
    # A non-contiguous view is accepted too (copied once).
    images["right"] = np.asfortranarray(images["right"])
    written = sl.write_image_set(tmp_path / "set", rig, spec, images, encoding=encoding,
                                 exposure_us=1234.0, extra={"note": "from numpy"})
    opened = sl.ImageSet.open(tmp_path / "set")
    assert opened.cameras == written.cameras == ["left", "right"]
    assert opened.pattern_count == spec.num_images
    assert opened.extra["note"] == "from numpy"
    assert opened.patterns.to_dict() == spec.to_dict()
    assert opened.rig.to_dict() == rig.to_dict()
    for camera, stack in images.items():
        back = opened.images(camera)
        assert back.dtype == dtype
        np.testing.assert_array_equal(back, stack)
        np.testing.assert_array_equal(opened.image(camera, 7), stack[7])


def test_write_image_set_refuses_and_keeps_existing(tmp_path):
    rig = sl.Rig.load(QUARTER_RIG)
    spec = sl.PatternSpec.load(DEMO_PATTERNS)
    ok = {c: np.zeros((spec.num_images, 300, 480), np.uint8) for c in rig.camera_names}
    sl.write_image_set(tmp_path / "set", rig, spec, ok)
    before = sorted(p.name for p in (tmp_path / "set").rglob("*"))
    with pytest.raises(sl.Error, match="exists"):
        sl.write_image_set(tmp_path / "set", rig, spec, ok)
    wrong = dict(ok, right=np.zeros((spec.num_images, 300, 481), np.uint8))
    with pytest.raises(sl.Error, match="right"):
        sl.write_image_set(tmp_path / "set", rig, spec, wrong, overwrite=True)
    assert sorted(p.name for p in (tmp_path / "set").rglob("*")) == before
    with pytest.raises(sl.Error, match="float"):
        sl.write_image_set(tmp_path / "f", rig, spec, {"left": np.zeros((38, 300, 480))})


def test_rig_save_load(tmp_path):
    rig = sl.Rig.load(QUARTER_RIG)
    for name in ("rig.yaml", "rig.json"):
        rig.save(tmp_path / name)
        assert sl.Rig.load(tmp_path / name).to_dict() == rig.to_dict()
    assert sl.Rig.from_dict(rig.to_dict()).to_dict() == rig.to_dict()
    assert rig.camera_names == ["left", "right"] and rig.projector.name == "projector"
    assert rig.camera("right").model.width == 480


def test_project_unproject_every_device():
    rig = sl.Rig.load(QUARTER_RIG)
    rng = np.random.default_rng(7)
    for device in rig.cameras + [rig.projector]:
        m = device.model
        pixels = np.column_stack([rng.uniform(0, m.width - 1, 500), rng.uniform(0, m.height - 1, 500)])
        rays, ok = m.unproject(pixels)
        assert ok.all()
        np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1, atol=1e-12)
        back, ok = m.project(rays * rng.uniform(100, 900, (500, 1)))
        assert ok.all()
        np.testing.assert_allclose(back, pixels, atol=1e-6)
        # The rig frame: a point on a device ray projects back to its pixel.
        rays_rig, ok = device.unproject(pixels)
        points = device.center_in_rig + rays_rig * 500.0
        back, ok = device.project(points)
        np.testing.assert_allclose(back, pixels, atol=1e-6)
        # cam_from_rig maps the centre to the origin.
        c = device.cam_from_rig @ np.append(device.center_in_rig, 1)
        np.testing.assert_allclose(c[:3], 0, atol=1e-9)
    pixel, ok = rig.cameras[0].model.project(np.array([0.0, 0.0, -5.0]))
    assert not ok and np.isnan(pixel).all()


def test_point_cloud_ply_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    points = rng.normal(size=(1000, 3)) * 100
    normals = rng.normal(size=(1000, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    colors = rng.integers(0, 255, size=(1000, 3)).astype(np.uint8)
    quality = rng.uniform(size=1000).astype(np.float32)
    cloud = sl.PointCloud(points, normals, colors, {"quality": quality})
    assert not cloud.points.flags.writeable
    for binary in (True, False):
        path = tmp_path / f"c{int(binary)}.ply"
        cloud.write_ply(path, binary=binary)
        back = sl.read_ply(path)
        np.testing.assert_array_equal(back.points, points)
        np.testing.assert_array_equal(back.normals, normals.astype(np.float32))
        np.testing.assert_array_equal(back.colors, colors)
        np.testing.assert_array_equal(back.scalar("quality"), quality)
        oracle = read_vertices(path)
        np.testing.assert_array_equal(oracle["x"], points[:, 0])
    with pytest.raises(sl.Error, match="quality"):
        sl.PointCloud(points, scalars={"quality": quality[:10]})
