"""Bad input raises slshadow.Error with the command line's one-line message; long calls release
the GIL (another Python thread runs meanwhile); repeated calls do not grow the process."""

import threading
import sys
import time

import numpy as np
import pytest

import slshadow as sl
from conftest import DEMO_PATTERNS, DEMO_SCENE, QUARTER_RIG, cli_error


def one_line(error):
    message = str(error.value)
    assert "\n" not in message and message
    return message


def test_missing_rig_file_message_is_the_cli_one(tmp_path):
    missing = tmp_path / "no_such_rig.yaml"
    with pytest.raises(sl.Error) as e:
        sl.Rig.load(missing)
    assert one_line(e) == cli_error("rig", "show", missing)
    assert str(missing) in str(e.value)


def test_bad_rig_field_message_is_the_cli_one(tmp_path):
    bad = tmp_path / "bad_rig.yaml"
    bad.write_text(QUARTER_RIG.read_text().replace("fx: 682.5", "fx: -3", 1))
    with pytest.raises(sl.Error) as e:
        sl.Rig.load(bad)
    assert one_line(e) == cli_error("rig", "show", bad)
    assert "fx" in str(e.value) and "-3" in str(e.value)


def test_folder_without_manifest_message_is_the_cli_one(tmp_path):
    empty = tmp_path / "not_an_imageset"
    empty.mkdir()
    with pytest.raises(sl.Error) as e:
        sl.ImageSet.open(empty)
    assert one_line(e) == cli_error("reconstruct", empty, "--out", tmp_path / "x.ply")


def test_bad_pattern_spec_message_is_the_cli_one(tmp_path):
    bad = tmp_path / "bad_patterns.yaml"
    bad.write_text(DEMO_PATTERNS.read_text().replace("phase_steps: 4", "phase_steps: 2"))
    with pytest.raises(sl.Error) as e:
        sl.PatternSpec.load(bad)
    assert one_line(e) == cli_error("patterns", "show", bad)


def test_option_messages_are_the_cli_ones(cli_scan, tmp_path):
    """Keyword options are checked by the C++ code the command line runs: the message for a value
    is the command line's for the same value, word for word."""
    image_set = sl.ImageSet.open(cli_scan)
    out = tmp_path / "x.ply"
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, min_depth_mm=-5)
    assert one_line(e) == cli_error("reconstruct", cli_scan, "--out", out, "--min-depth-mm", "-5")
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, shadow_threshold=-5)
    cli_decode = cli_error("reconstruct", cli_scan, "--out", out, "--shadow-threshold", "-5")
    assert one_line(e) == cli_decode
    with pytest.raises(sl.Error) as e:
        sl.decode(image_set.images("left"), image_set.patterns, shadow_threshold=-5)
    assert one_line(e) == cli_decode
    cloud = tmp_path / "cloud.ply"
    sl.PointCloud(np.random.default_rng(2).normal(size=(50, 3))).write_ply(cloud)
    with pytest.raises(sl.Error) as e:
        sl.compare(cloud, cloud, threshold_mm=-1)
    assert one_line(e) == cli_error("compare", cloud, cloud, "--out", tmp_path / "report",
                                    "--threshold-mm", "-1")
    assert not out.exists() and not (tmp_path / "report").exists()


def test_option_names_and_types(cli_scan):
    image_set = sl.ImageSet.open(cli_scan)
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, method="hartley")
    assert "hartley" in one_line(e) and "optimal" in str(e.value)
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, mode="sideways")
    assert "sideways" in one_line(e)
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, min_depth_mm="near")
    assert "min_depth_mm" in one_line(e) and "near" in str(e.value)
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(image_set, no_such_option=1)
    assert "no_such_option" in one_line(e) and "min_depth_mm" in str(e.value)
    with pytest.raises(sl.Error) as e:
        sl.compare(np.zeros((10, 3)), np.ones((10, 3)), registration="magic")
    assert "magic" in one_line(e)
    with pytest.raises(sl.Error) as e:
        sl.decode(image_set.images("left")[:5], image_set.patterns)
    assert "5" in one_line(e)


def test_cameras_option_stereo_needs_the_rig_names(cli_scan):
    with pytest.raises(sl.Error) as e:
        sl.reconstruct(sl.ImageSet.open(cli_scan), mode="stereo", cameras=["left", "middle"])
    assert "middle" in one_line(e)


@pytest.fixture(scope="module")
def scan():
    return sl.simulate(sl.Rig.load(QUARTER_RIG), sl.Scene.load(DEMO_SCENE), DEMO_PATTERNS)


def test_another_thread_runs_while_reconstruct_runs(scan):
    """With a switch interval of 1000 s the interpreter never preempts a thread: the counting
    thread can only run while the main thread has released the GIL, i.e. inside the C++ call."""
    counter = [0]
    stop = threading.Event()

    def count():
        while not stop.is_set():
            counter[0] += 1
            time.sleep(0.0002)  # releases the GIL, so the main thread can take it back

    thread = threading.Thread(target=count)
    thread.start()
    while counter[0] == 0:
        time.sleep(0.001)
    old = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)
    try:
        during = []

        def progress(stage, done, total):
            during.append((stage, done, total, counter[0]))

        before = counter[0]
        rec = sl.reconstruct(scan, mode="stereo", method="optimal", progress=progress)
        after = counter[0]
    finally:
        sys.setswitchinterval(old)
        stop.set()
        thread.join()
    assert len(rec) > 1000
    assert after > before, "no other thread ran during reconstruct: the GIL was held"
    # Two cameras decoded, then the pair triangulated: three calls, the GIL taken back for each
    # (the counting thread ran between them too).
    assert [d[:3] for d in during] == [("reconstruct", 1, 3), ("reconstruct", 2, 3),
                                       ("reconstruct", 3, 3)]
    assert during[0][3] >= before and after >= during[-1][3]


def runs_of(calls):
    """(stage, done, total) calls cut into runs of one stage, asserting done rises within each
    run up to its total: [(stage, calls, total)]."""
    runs = []
    for stage, done, total in calls:
        assert 0 < done <= total, (stage, done, total)
        if runs and runs[-1][0] == stage and done > runs[-1][3]:
            assert total == runs[-1][2]
            runs[-1] = (stage, runs[-1][1] + 1, total, done)
        else:
            runs.append((stage, 1, total, done))
    assert all(last == total for _, _, total, last in runs), runs
    return [r[:3] for r in runs]


def test_progress_within_stages_from_worker_threads():
    """simulate reports per camera traced and per image rendered, reconstruct per camera decoded
    and triangulated; done rises within each stage (calls come from the library's threads with
    the GIL taken for each)."""
    calls, threads = [], set()

    def progress(stage, done, total):
        calls.append((stage, done, total))
        threads.add(threading.get_ident())

    scan = sl.simulate(sl.Rig.load(QUARTER_RIG), sl.Scene.load(DEMO_SCENE), DEMO_PATTERNS,
                       progress=progress)
    n = scan.patterns.num_images
    runs = runs_of(calls)
    assert runs[0] == ("trace", 2, 2)
    # Rendering reports per batch of images: at least one call per camera, done up to 2 n.
    assert runs[1][0] == "render" and runs[1][2] == 2 * n and runs[1][1] >= 2 and len(runs) == 2
    calls.clear()
    sl.reconstruct(scan, mode="projector", progress=progress)
    assert runs_of(calls) == [("reconstruct", 4, 4)]
    calls.clear()
    sl.reconstruct(scan, mode="stereo", progress=progress)
    assert runs_of(calls) == [("reconstruct", 3, 3)]


def test_progress_callback_error_propagates(scan):
    def fail(stage, done, total):
        raise KeyError("stop here")

    with pytest.raises(KeyError, match="stop here"):
        sl.reconstruct(scan, progress=fail)


def rss_kb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_200_calls_leave_rss_flat(scan):
    """A leak of one cloud per call (~ 100k points x 60 bytes) would add ~1 GB over 200 calls."""
    images = {camera: scan.images(camera) for camera in scan.cameras}
    reference = sl.PointCloud(np.random.default_rng(1).normal(size=(2000, 3)))

    def one_call():
        rec = sl.reconstruct(images, scan.patterns, rig=scan.rig, mode="projector")
        assert len(rec) > 1000
        _ = rec.points, rec.normals, rec.source_pixel, rec.summaries
        result = sl.compare(rec, reference, threshold_mm=1.0)
        _ = result.deviations, result.figures
        return len(rec)

    for _ in range(20):  # warm-up: pools and caches reach their steady size
        one_call()
    start = rss_kb()
    for _ in range(200):
        one_call()
    growth_mb = (rss_kb() - start) / 1024
    print(f"RSS growth over 200 reconstruct + compare calls: {growth_mb:.1f} MB")
    assert growth_mb < 100
