"""slshadow.sweep against `slshadow sweep study` on the same small study: the same results.csv
and results.json byte for byte (sweeps are deterministic), and the tables as arrays equal to the
CSV the command writes."""

import csv

import numpy as np

import slshadow as sl
from conftest import SOURCE_DIR, run_cli


def small_study(tmp_path):
    study = tmp_path / "study.yaml"
    study.write_text(f"""format: slshadow-study
version: 1
name: python-small
rig: {SOURCE_DIR / 'config' / 'studies' / 'quarter_demo_rig.yaml'}
modes: [projector, stereo]
compare: {{threshold_mm: 0.5}}
axes:
  - name: albedo
    set: scene.objects.0.albedo
    values: [0.7, 0.2]
""")
    return study


def test_sweep_matches_cli(tmp_path):
    study = small_study(tmp_path)
    run_cli("sweep", "study", study, "--out", tmp_path / "cli")
    calls = []
    result = sl.sweep(study, tmp_path / "py", progress=lambda *a: calls.append(a))
    # One call per job (two albedo values: two jobs), between the plan and the merge.
    assert calls == [("plan", 0, 1), ("plan", 1, 1), ("jobs", 1, 2), ("jobs", 2, 2), ("done", 1, 1)]
    assert result["plan"]["jobs"] == 2 and result["plan"]["axes"] == ["albedo"]
    assert result["run"]["ran"] == 2 and not result["resumed"]
    assert result["merge"]["rows"] == 4
    for name in ("results.csv", "results.json"):
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()
    table = result["tables"]["results"]
    with open(tmp_path / "cli" / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4 and list(table) == list(rows[0])
    for column, values in table.items():
        assert len(values) == 4
        for value, row in zip(values, rows):
            if values.dtype.kind == "f":
                assert (np.isnan(value) and row[column] == "") or value == float(row[column])
            else:
                assert value == row[column]
    assert list(table["id"]) == ["000000", "000000", "000001", "000001"]
    assert list(table["mode"]) == ["projector", "stereo"] * 2
    assert table["rms_mm"].dtype == np.float64 and np.all(table["rms_mm"] > 0)
    np.testing.assert_array_equal(table["albedo"], [0.7, 0.7, 0.2, 0.2])
    # A second call resumes: nothing runs again.
    again = sl.sweep(study, tmp_path / "py")
    assert again["resumed"] and again["run"]["ran"] == 0 and again["run"]["already_done"] == 2
