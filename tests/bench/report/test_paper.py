"""The paper's values go beside ours only on the drives and cameras that stand for the paper's."""

import pytest

from bench.report.paper.values import PAPER_TABLE23, data_label, paper_drive, table1_applies


@pytest.mark.parametrize("config, which, expected", [
    ({"name": "synthetic", "params": {}}, "calibration", "540m"),
    ({"name": "synthetic", "params": {}}, "holdout", "928m"),
    ({"name": "synthetic", "params": {"drives": ["paper_928m"], "holdout": None}}, "calibration", "928m"),
    ({"name": "synthetic", "params": {"holdout": None}}, "holdout", None),
    ({"name": "synthetic", "params": {"drive": "paper_540m"}}, "calibration", "540m"),  # older records
    ({"name": "kitti00", "params": {"drives": ["paper_540m"], "holdout": "clean_928m"}}, "holdout", "928m"),
    ({"name": "kitti00", "params": {"drives": [[15, 796]]}}, "calibration", "540m"),
    ({"name": "kitti00", "params": {"holdout": [2404, 2684]}}, "holdout", None),
    ({"name": "kitti00_tracks", "params": {"window": [15, 153]}}, "calibration", None),
    ({"name": "euroc", "params": {}}, "calibration", None),
])
def test_paper_drive(config, which, expected):
    assert paper_drive(config, which) == expected


def test_table1_and_labels():
    assert table1_applies("kitti00") and table1_applies("synthetic") and not table1_applies("euroc")
    assert "simulated camera" in data_label("kitti00") and "simulated IMU" in data_label("synthetic")
    assert PAPER_TABLE23[("540m", "position")]["AVIO"] == (2.0736, 1.7936, 0.8551)


def test_table1_says_which_variables_were_frozen_or_tied():
    from bench.report.paper.tables import _frozen_note

    note = _frozen_note({"name": "synthetic", "params": {"fixed": ["dy", "dz"], "tie_focal": True}})
    assert "frozen at the reference, not calibrated: dy, dz" in note and "fy tied to fx" in note
    assert _frozen_note({"name": "synthetic", "params": {"fixed": [], "tie_focal": False}}) == ""
