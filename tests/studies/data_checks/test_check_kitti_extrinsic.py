"""studies/data_checks/check_kitti_extrinsic.py: the camera orientation the real KITTI tracks imply, against the
calibration chain of the ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation


@pytest.fixture(scope="module")
def data(shared_data: Path, skip_no_data) -> Path:
    if not (shared_data / "kitti00" / "VO_stereo_factors00.txt").exists():
        skip_no_data(f"{shared_data / 'kitti00'} lacks the KITTI 00 tracks (VO_stereo_factors00.txt)")
    return shared_data


@pytest.mark.parametrize("method", ["essential", "pnp"])
def test_a_known_turn_of_the_chain_moves_the_estimate_by_minus_that_turn(method, load_script, data):
    check = load_script("check_kitti_extrinsic")
    base = np.median(check.direction_offsets(data, 15, 153, method=method), axis=0)  # (about y, about x) deg
    for axis, turn in ((1, 0.5), (0, -0.4)):  # camera y (the estimate's first column) and x
        delta = Rotation.from_rotvec(np.radians(turn) * np.eye(3)[axis]).as_matrix()
        moved = np.median(check.direction_offsets(data, 15, 153, chain_rotation=delta, method=method), axis=0)
        # D_y is the first column, D_x minus the second: both move by -turn
        change = moved[0] - base[0] if axis == 1 else -(moved[1] - base[1])
        assert change == pytest.approx(-turn, abs=0.05)


@pytest.mark.parametrize("method", ["essential", "pnp"])
def test_the_tracks_say_the_rectified_extrinsic_is_off_about_the_camera_x_axis(method, load_script, data):
    offsets = load_script("check_kitti_extrinsic").direction_offsets(data, 15, 153, method=method)
    assert len(offsets) >= 90
    # ~0.42 deg about x, 6-12 bootstrap SEs (README: "The rectified extrinsic is not the camera's true orientation")
    assert 0.2 < np.median(offsets[:, 1]) < 0.7
