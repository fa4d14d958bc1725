"""Decoding the paper and local calibration spaces."""

from __future__ import annotations

import numpy as np
import pytest

from avio.geometry import geodesic_angle_deg
from avio.reference import PAPER_TABLE1, kitti_2011_10_03_calibration
from bench.problems.calibration_space import make_calibration_space
from bench.space import SpaceError


@pytest.mark.parametrize("kind", ["paper", "local"])
@pytest.mark.parametrize("with_td", [False, True])
def test_decode_inverts_encode_and_the_reference_decodes_to_the_nominal(kind, with_td):
    nominal = kitti_2011_10_03_calibration()
    cs = make_calibration_space(kind, nominal, with_time_offset=with_td, image_size_px=(1241, 376))
    rng = np.random.default_rng(1)
    X = rng.uniform(cs.space.lower, cs.space.upper, size=(5, cs.space.dim))
    cal = cs.decode(X)
    again = cs.decode(cs.encode(cal))
    # Euler angles past pitch = -90 deg re-encode as another triple of the same rotation
    assert np.all(geodesic_angle_deg(cal.R_cam_imu, again.R_cam_imu) < 1e-7)
    np.testing.assert_allclose(again.p_imu_cam_m, cal.p_imu_cam_m, atol=1e-12)
    np.testing.assert_allclose(again.fx_px, X[:, 0])
    np.testing.assert_allclose(cs.encode(cal), X, atol=1e-7)  # the Euler branch nearest the reference
    ref = cs.decode(cs.space.reference[None])
    assert geodesic_angle_deg(ref.R_cam_imu[0], nominal.R_cam_imu[0]) < 1e-9
    np.testing.assert_allclose(ref.p_imu_cam_m, nominal.p_imu_cam_m, atol=1e-12)
    assert cs.space.dim == 10 + with_td


def test_paper_space_reference_matches_table1():
    cs = make_calibration_space("paper", kitti_2011_10_03_calibration())
    table_ref = np.array([v[0] for v in PAPER_TABLE1.values()])
    np.testing.assert_allclose(cs.space.reference, table_ref, atol=5e-3)


def test_paper_pso_ga_point_is_0_23_deg_from_the_reference():
    """docs/model.md, Eq. 4 (gimbal lock): 12.8 deg apart per angle, 0.23 deg apart as rotations (gimbal lock)."""
    cs = make_calibration_space("paper", kitti_2011_10_03_calibration())
    psoga = np.array([v[3] for v in PAPER_TABLE1.values()])
    cal = cs.decode(np.stack([cs.space.reference, psoga]))
    assert geodesic_angle_deg(cal.R_cam_imu[0], cal.R_cam_imu[1]) == pytest.approx(0.23, abs=0.01)


def test_bad_space_names_and_bounds_are_reported():
    nominal = kitti_2011_10_03_calibration()
    with pytest.raises(SpaceError, match="unknown space 'polar'"):
        make_calibration_space("polar", nominal)
    with pytest.raises(SpaceError, match="unknown variable 'fz'"):
        make_calibration_space("paper", nominal, bounds={"fz": [0, 1]})
    with pytest.raises(SpaceError, match="variable 'fx': lower bound 750.0 is not below"):
        make_calibration_space("paper", nominal, bounds={"fx": [750, 700]})


def test_rectified_reference_leaves_table1_bounds_because_of_gimbal_lock():
    """0.65 deg of rectification swings ZYX roll from 119.5 to 173 deg (roll + yaw is kept)."""
    rectified = kitti_2011_10_03_calibration(rectified=True)
    with pytest.raises(SpaceError, match="variable 'roll': reference 173.0"):
        make_calibration_space("paper", rectified)
    local = make_calibration_space("local", rectified, image_size_px=(1241, 376))
    np.testing.assert_allclose(local.space.reference[4:], 0.0, atol=1e-12)


def test_local_intrinsics_range_comes_from_the_rig_not_from_table_1():
    from avio.calibration import Calibration

    euroc_like = Calibration.single(458.654, 457.296, 367.215, 248.375, np.eye(3), np.zeros(3))
    space = make_calibration_space("local", euroc_like, image_size_px=(752, 480)).space
    lo, hi = dict(zip(space.names, space.lower)), dict(zip(space.names, space.upper))
    assert lo["fx"] == pytest.approx(458.654 - 0.03 * 458.654) and hi["cx"] == pytest.approx(367.215 + 0.02 * 752)
    with pytest.raises(SpaceError, match="image size"):
        make_calibration_space("local", euroc_like)
