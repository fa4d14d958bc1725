"""EuRoC V1_01 loader: the real files (shapes, clocks, frame conventions, calibration, tracks)
and clear errors on broken copies of them."""

from __future__ import annotations

import shutil
import sys
from importlib import import_module
from pathlib import Path

import numpy as np
import pytest

from avio.calibration import Calibration
from avio.datasets.euroc import (
    CAMCHAIN_FILE,
    FEATURES_FILE,
    GRAVITY_MPS2,
    GT_FILE,
    IMU_CHAIN_FILE,
    EurocDataError,
    load_euroc,
    read_euroc,
)
from avio.datasets.kalibr import read_camchain, read_imu_noise, read_kalibr_yaml
from avio.geometry import geodesic_angle_deg, so3_log
from avio.sequence import ImuSamples


@pytest.fixture(scope="module")
def euroc_dir(shared_data: Path, skip_no_data) -> Path:
    path = shared_data / "euroc_v1_01"
    if not (path / FEATURES_FILE).is_file():
        skip_no_data(f"{path} lacks {FEATURES_FILE}")
    return path


@pytest.fixture(scope="module")
def flight(euroc_dir):
    return load_euroc(euroc_dir, 0.0, 30.0)


def _mean_gyro(imu: ImuSamples, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """(n, 3) gyro averaged over [t0, t1] (trapezoid integral / duration)."""
    from scipy.integrate import cumulative_trapezoid

    cum = cumulative_trapezoid(imu.gyro_imu_radps, imu.t_s, axis=0, initial=0.0)
    def at(t):
        return np.stack([np.interp(t, imu.t_s, cum[:, j]) for j in range(3)], 1)
    return (at(t1) - at(t0)) / (t1 - t0)[:, None]


def _filter_model():
    """tests/avio/filter/filter_model.py: test folders are no packages (pytest's prepend import mode),
    and a ``tests`` package of another distribution in site-packages would shadow ``tests.avio``."""
    folder = str(Path(__file__).resolve().parents[1] / "filter")
    if folder not in sys.path:
        sys.path.insert(0, folder)
    return import_module("filter_model")


def _triplet_residuals_under_truth(seq, cal: Calibration) -> np.ndarray:
    relative_poses, triplet_residuals = _filter_model().relative_poses, _filter_model().triplet_residuals
    """(m, 4) pixel residuals of every valid triplet feature under the ground-truth poses."""
    R_world_cam = seq.truth.R_world_imu @ cal.R_cam_imu[0].T
    p_world_cam = seq.truth.p_world_imu_m + seq.truth.R_world_imu @ cal.p_imu_cam_m[0]
    k = seq.tracks.frame_index
    R12, t12, R13, t13 = relative_poses(np.stack([R_world_cam[k - 2], R_world_cam[k - 1], R_world_cam[k]]),
                                        np.stack([p_world_cam[k - 2], p_world_cam[k - 1], p_world_cam[k]]))
    out = []
    # triplet_residuals shares one feature set across its batch, so it is called per triplet.
    for j in range(len(k)):
        uv = seq.tracks.uv_px[j][seq.tracks.valid[j]]
        r, _ = triplet_residuals(uv, R12[j:j + 1], t12[j:j + 1], R13[j:j + 1], t13[j:j + 1],
                                 cal.fx_px, cal.fy_px, cal.cx_px, cal.cy_px)
        out.append(r[0])
    return np.concatenate(out)


# ---------------------------------------------------------------- real data


@pytest.mark.data
def test_shapes_of_the_30s_flight(flight):
    N = flight.n_frames
    assert N == 601
    assert flight.truth.p_world_imu_m.shape == (N, 3) and flight.truth.R_world_imu.shape == (N, 3, 3)
    assert flight.truth.v_world_imu_mps.shape == (N, 3)
    assert flight.imu.accel_imu_mps2.shape == (6001, 3)
    assert flight.tracks.uv_px.shape[0] == N - 2 and flight.tracks.uv_px.shape[2:] == (3, 2)
    np.testing.assert_array_equal(flight.tracks.frame_index, np.arange(2, N))
    assert np.median(flight.tracks.n_features) >= 20 and flight.tracks.n_features.min() >= 5
    assert flight.image_size_px == (752, 480)
    assert flight.truth_calibration is None
    assert 8.0 < flight.path_length_m() < 8.5  # data README: 8.2 m of path


@pytest.mark.data
@pytest.mark.parametrize("window, frames", [((0.0, 20.0), (0, 400)), ((20.0, 30.0), (400, 600))])
def test_windows_select_the_frames_of_their_time_span(euroc_dir, window, frames):
    seq = load_euroc(euroc_dir, *window)
    assert (seq.meta["first_frame"], seq.meta["last_frame"]) == frames
    np.testing.assert_allclose(seq.frame_t_s[[0, -1]], window, atol=1e-3)
    np.testing.assert_allclose(seq.truth.p_world_imu_m[0], 0.0, atol=1e-12)


@pytest.mark.data
def test_frames_have_truth_rows_within_1ms_and_the_imu_covers_the_window(euroc_dir, flight):
    raw = read_euroc(euroc_dir)
    assert raw.gt_dt_s.max() < 1e-3
    for seq in (flight, load_euroc(euroc_dir, 20.0, 30.0)):
        assert seq.imu.t_s[0] <= seq.frame_t_s[0] and seq.imu.t_s[-1] >= seq.frame_t_s[-1]
        assert np.diff(seq.imu.t_s).max() < 0.0051  # 200 Hz, no gap
    np.testing.assert_allclose(np.diff(flight.frame_t_s), 0.05, atol=1e-5)


@pytest.mark.data
def test_gyro_matches_the_ground_truth_body_rate_so_imu_frame_is_the_body_frame(euroc_dir, flight):
    raw = read_euroc(euroc_dir)
    R = flight.truth.R_world_imu
    t = flight.frame_t_s
    # Body rate from consecutive truth rotations (R_k^T R_k+1 = exp(w dt)) against the gyro
    # averaged over the same interval minus the truth gyro bias.
    rate_truth = so3_log(np.swapaxes(R[:-1], 1, 2) @ R[1:]) / np.diff(t)[:, None]
    rate_gyro = _mean_gyro(flight.imu, t[:-1], t[1:]) - raw.gt_gyro_bias_radps[:-1]
    corr = [np.corrcoef(rate_truth[:, j], rate_gyro[:, j])[0, 1] for j in range(3)]
    assert min(corr) > 0.9, corr
    # The transposed attitude (a world-to-body quaternion read as body-to-world) would not fit.
    R_wrong = np.swapaxes(R, 1, 2)
    rate_wrong = so3_log(np.swapaxes(R_wrong[:-1], 1, 2) @ R_wrong[1:]) / np.diff(t)[:, None]
    assert min(np.corrcoef(rate_wrong[:, j], rate_gyro[:, j])[0, 1] for j in range(3)) < 0.9


@pytest.mark.data
def test_world_is_gravity_aligned_z_up(flight):
    # Before take-off (t < 4 s) the specific force rotated to the world is -g: +9.81 along +z.
    still = flight.imu.t_s < 4.0
    R_at_imu = flight.truth.R_world_imu[np.searchsorted(flight.frame_t_s, flight.imu.t_s[still])]
    f_world = np.einsum("nij,nj->i", R_at_imu, flight.imu.accel_imu_mps2[still]) / still.sum()
    np.testing.assert_allclose(flight.gravity_world_mps2, [0.0, 0.0, -GRAVITY_MPS2])
    np.testing.assert_allclose(f_world, -flight.gravity_world_mps2, atol=0.1)


@pytest.mark.data
def test_velocities_are_the_derivative_of_the_positions(flight):
    v_fd = np.diff(flight.truth.p_world_imu_m, axis=0) / np.diff(flight.frame_t_s)[:, None]
    v_mid = 0.5 * (flight.truth.v_world_imu_mps[1:] + flight.truth.v_world_imu_mps[:-1])
    assert np.median(np.linalg.norm(v_fd - v_mid, axis=1)) < 0.01


@pytest.mark.data
def test_reference_calibration_is_kalibr_cam0_with_the_camera_looking_along_z_imu(euroc_dir, flight):
    cal = flight.reference_calibration
    T_imu_cam = np.array(read_kalibr_yaml(euroc_dir / CAMCHAIN_FILE)["cam0"]["T_imu_cam"])
    np.testing.assert_allclose(np.linalg.det(cal.R_cam_imu[0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(cal.R_cam_imu[0], T_imu_cam[:3, :3].T, atol=1e-9)
    np.testing.assert_allclose(cal.p_imu_cam_m[0], T_imu_cam[:3, 3])
    z_cam_in_imu = cal.R_cam_imu[0].T @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(z_cam_in_imu[2])) < 3.0  # data README: 1.5 deg off +z_imu
    np.testing.assert_allclose([cal.fx_px[0], cal.fy_px[0], cal.cx_px[0], cal.cy_px[0]],
                               [458.654, 457.296, 367.215, 248.375])
    assert cal.time_offset_s[0] == 0.0
    noise = flight.imu_noise
    assert (noise.accel_noise, noise.gyro_noise, noise.accel_bias_walk, noise.gyro_bias_walk) == (
        2.0e-3, 1.6968e-4, 3.0e-3, 1.9393e-5)


@pytest.mark.data
def test_most_feature_pixels_are_inside_the_image(flight):
    uv = flight.tracks.uv_px[flight.tracks.valid]
    W, H = flight.image_size_px
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    # Undistorting the barrel-distorted edges pushes a quarter of the points past the border.
    assert inside.mean() > 0.7
    assert np.median(np.abs(uv[..., 0] - W / 2)) < W / 2 and np.median(np.abs(uv[..., 1] - H / 2)) < H / 2


@pytest.mark.data
def test_tracks_fit_the_ground_truth_poses_under_kalibr(flight):
    r = _triplet_residuals_under_truth(flight, flight.reference_calibration)
    assert np.median(np.abs(r[:, :2])) < 0.15  # epipolar (Sampson) distances, px
    assert np.median(np.abs(r[:, 2:])) < 0.3  # point transfer, px
    assert np.mean(np.abs(r[:, :2]) < 2.0) > 0.97  # ~1.6 % gross outliers (data README)
    # The classic trap: the extrinsic without its transpose explains nothing.
    cal = flight.reference_calibration
    wrong = Calibration.single(cal.fx_px[0], cal.fy_px[0], cal.cx_px[0], cal.cy_px[0],
                               cal.R_cam_imu[0].T, cal.p_imu_cam_m[0])
    assert np.median(np.abs(_triplet_residuals_under_truth(flight, wrong)[:, :2])) > 1.0


@pytest.mark.data
def test_initial_gyro_bias_from_the_truth_or_the_standstill(euroc_dir, flight):
    raw = read_euroc(euroc_dir)
    np.testing.assert_array_equal(flight.initial_gyro_bias_radps, raw.gt_gyro_bias_radps[0])
    assert flight.initial_accel_bias_mps2 is None
    still = load_euroc(euroc_dir, 0.0, 30.0, gyro_bias_init="standstill", accel_bias_init="ground_truth")
    t_a, t_b = still.meta["standstill_s"]
    assert t_a == 0.0 and 4.0 < t_b < 5.5  # the MAV takes off after ~5 s
    np.testing.assert_allclose(still.initial_gyro_bias_radps, raw.gt_gyro_bias_radps[0], atol=3e-3)
    np.testing.assert_array_equal(still.initial_accel_bias_mps2, raw.gt_accel_bias_mps2[0])
    assert load_euroc(euroc_dir, 0.0, 30.0, gyro_bias_init="zero").initial_gyro_bias_radps is None
    with pytest.raises(EurocDataError, match="start at rest"):
        load_euroc(euroc_dir, 20.0, 30.0, gyro_bias_init="standstill")


@pytest.mark.data
def test_content_hash_identifies_the_data_and_settings(euroc_dir, flight):
    assert load_euroc(euroc_dir, 0.0, 30.0).meta["content_hash"] == flight.meta["content_hash"]
    others = {load_euroc(euroc_dir, 0.0, 20.0).meta["content_hash"],
              load_euroc(euroc_dir, 0.0, 30.0, max_features=12).meta["content_hash"],
              load_euroc(euroc_dir, 0.0, 30.0, gyro_bias_init="zero").meta["content_hash"]}
    assert len(others) == 3 and flight.meta["content_hash"] not in others


@pytest.mark.data
def test_max_features_caps_each_triplet(euroc_dir):
    seq = load_euroc(euroc_dir, 20.0, 30.0, max_features=10, seed=1)
    assert seq.tracks.n_features.max() == 10


@pytest.mark.data
@pytest.mark.parametrize("window", [(0.0, 31.0), (-1.0, 10.0), (10.0, 5.0), (10.0, 10.05)])
def test_windows_outside_the_data_are_errors(euroc_dir, window):
    with pytest.raises(EurocDataError, match="window"):
        load_euroc(euroc_dir, *window)


@pytest.fixture
def copy_dir(euroc_dir, tmp_path) -> Path:
    for name in (FEATURES_FILE, GT_FILE, CAMCHAIN_FILE, IMU_CHAIN_FILE):
        shutil.copy(euroc_dir / name, tmp_path / name)
    return tmp_path


def _rewrite(path: Path, edit) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(edit(lines)))


@pytest.mark.data
@pytest.mark.parametrize("name", [FEATURES_FILE, GT_FILE, CAMCHAIN_FILE, IMU_CHAIN_FILE])
def test_a_missing_file_is_named(copy_dir, name):
    (copy_dir / name).unlink()
    with pytest.raises(EurocDataError, match=f"{name}: file not found"):
        load_euroc(copy_dir)


@pytest.mark.data
def test_a_corrupt_imu_row_names_its_line(copy_dir):
    path = copy_dir / FEATURES_FILE
    lines = path.read_text().splitlines(keepends=True)
    n = [i for i, line in enumerate(lines) if line.startswith("imu,")][100]
    fields = lines[n].split(",")
    fields[6] = "abc"  # the gx column
    lines[n] = ",".join(fields)
    path.write_text("".join(lines))
    with pytest.raises(EurocDataError, match=f"{FEATURES_FILE}:{n + 1}: imu row has no valid gx"):
        load_euroc(copy_dir)


@pytest.mark.data
def test_a_corrupt_ground_truth_row_names_its_line(copy_dir):
    _rewrite(copy_dir / GT_FILE, lambda ls: ls[:5] + ["1403715273462142976,0.1,0.2\n"] + ls[6:])
    with pytest.raises(EurocDataError, match=f"{GT_FILE}:6: expected 17 numbers"):
        load_euroc(copy_dir)


@pytest.mark.data
def test_imu_that_stops_before_the_window_ends_is_an_error(copy_dir):
    def drop_late_imu(lines):
        return [ln for ln in lines if not (ln.startswith("imu,") and float(ln.split(",")[2]) > 25.0)]

    _rewrite(copy_dir / FEATURES_FILE, drop_late_imu)
    with pytest.raises(EurocDataError, match=r"IMU covers \[0.0000, 25.0000\] s"):
        load_euroc(copy_dir, 0.0, 30.0)
    assert load_euroc(copy_dir, 0.0, 20.0).n_frames == 401  # windows it covers still load


@pytest.mark.data
def test_ground_truth_that_misses_a_frame_is_an_error(copy_dir):
    _rewrite(copy_dir / GT_FILE, lambda ls: ls[:11] + ls[12:])  # the row of frame 10
    with pytest.raises(EurocDataError, match="no ground-truth row within 1 ms of frame 10"):
        load_euroc(copy_dir)


@pytest.mark.data
def test_feature_intrinsics_must_agree_with_kalibr(copy_dir):
    _rewrite(copy_dir / CAMCHAIN_FILE, lambda ls: [ln.replace("458.654", "460.0") for ln in ls])
    with pytest.raises(EurocDataError, match="undistorted with intrinsics"):
        load_euroc(copy_dir)


# ---------------------------------------------------------------- no data needed


def test_kalibr_yaml_with_its_opencv_directive_is_read(tmp_path):
    path = tmp_path / "chain.yaml"
    path.write_text("%YAML:1.0\n\ncam0:\n  T_imu_cam:\n    - [0.0, -1.0, 0.0, 0.1]\n"
                    "    - [1.0, 0.0, 0.0, 0.2]\n    - [0.0, 0.0, 1.0, 0.3]\n    - [0.0, 0.0, 0.0, 1.0]\n"
                    "  intrinsics: [400.0, 401.0, 320.0, 240.0]\n  resolution: [640, 480]\n")
    cal, size = read_camchain(path)
    assert size == (640, 480)
    # T_imu_cam maps camera points into the IMU frame: x_cam is +y_imu.
    np.testing.assert_allclose(cal.R_cam_imu[0] @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(cal.p_imu_cam_m[0], [0.1, 0.2, 0.3])
    assert (cal.fx_px[0], cal.fy_px[0], cal.cx_px[0], cal.cy_px[0]) == (400.0, 401.0, 320.0, 240.0)


def test_kalibr_yaml_errors_name_file_line_and_key(tmp_path):
    path = tmp_path / "chain.yaml"
    path.write_text("%YAML:1.0\ncam0:\n  intrinsics: [1, 2\n  resolution: [640, 480]\n")
    with pytest.raises(EurocDataError, match=r"chain.yaml:\d+: not valid YAML"):
        read_camchain(path, error=EurocDataError)
    path.write_text("%YAML:1.0\ncam0:\n  intrinsics: [400.0, 401.0, 320.0, 240.0]\n")
    with pytest.raises(EurocDataError, match="missing key cam0.T_imu_cam"):
        read_camchain(path, error=EurocDataError)
    path.write_text("imu0:\n  accelerometer_noise_density: 2.0e-3\n  gyroscope_noise_density: x\n")
    with pytest.raises(EurocDataError, match="imu0.gyroscope_noise_density is not numeric"):
        read_imu_noise(path, error=EurocDataError)
    with pytest.raises(EurocDataError, match="EuRoC data folder not found"):
        load_euroc(tmp_path / "absent")


@pytest.mark.data
def test_a_nominal_perturbation_makes_kalibr_the_truth(euroc_dir, flight):
    seq = load_euroc(euroc_dir, 0.0, 30.0, nominal_perturbation={
        "d_intrinsics_px": (3.0, -2.0, 4.0, -3.0), "d_rotvec_cam_rad": (0.0, 0.0, 0.01),
        "d_p_imu_cam_m": (0.02, 0.0, 0.0)})
    kalibr = flight.reference_calibration
    for name in Calibration.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(seq.truth_calibration, name), getattr(kalibr, name))
    angle = geodesic_angle_deg(seq.truth_calibration.R_cam_imu, seq.reference_calibration.R_cam_imu)
    np.testing.assert_allclose(angle, np.degrees(0.01), rtol=1e-6)
    assert seq.reference_calibration.fx_px[0] == kalibr.fx_px[0] + 3.0
    np.testing.assert_allclose(seq.reference_calibration.p_imu_cam_m[0] - kalibr.p_imu_cam_m[0], [0.02, 0, 0])
    assert seq.meta["content_hash"] != flight.meta["content_hash"]
    with pytest.raises(EurocDataError, match="nominal_perturbation"):
        load_euroc(euroc_dir, 0.0, 30.0, nominal_perturbation={"d_focal": 1.0})
