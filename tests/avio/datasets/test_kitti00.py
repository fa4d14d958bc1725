"""KITTI sequence 00 loader: real-data figures, and clear errors on small synthetic folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from avio.calibration import CalibrationPerturbation
from avio.datasets.kitti00 import (
    GT_FILE,
    IMU_FILE,
    TIME_OFFSET_S,
    TIMES_FILE,
    TRACKS_FILE,
    WINDOWS,
    KittiDataError,
    estimate_gravity_gt_world,
    imu_poses_in_gt_world,
    load_kitti00,
)
from avio.geometry import geodesic_angle_deg, so3_exp, so3_log
from avio.reference import T_cam_imu_2011_10_03, kitti_2011_10_03_calibration
from avio.sequence import ImuSamples


def _mean_rate(imu: ImuSamples, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """(n, 3) gyro averaged over [t0, t1] (trapezoid integral / duration)."""
    cum = cumulative_trapezoid(imu.gyro_imu_radps, imu.t_s, axis=0, initial=0.0)
    def at(t):
        return np.stack([np.interp(t, imu.t_s, cum[:, j]) for j in range(3)], 1)
    return (at(t1) - at(t0)) / (t1 - t0)[:, None]


@pytest.fixture(scope="module")
def kitti00_dir(shared_data: Path, skip_no_data) -> Path:
    path = shared_data / "kitti00"
    if not (path / IMU_FILE).is_file():
        skip_no_data(f"{path} lacks {IMU_FILE}")
    return path


@pytest.fixture(scope="module")
def window540(kitti00_dir):
    return load_kitti00(kitti00_dir, *WINDOWS["paper_540m"], camera="simulated", seed=3)


# ---------------------------------------------------------------- real data


@pytest.mark.data
@pytest.mark.parametrize("name, length_m, duration_s", [("paper_540m", 542.0, 81.0), ("paper_928m", 927.0, 119.1)])
def test_paper_windows_have_the_papers_length_and_duration(kitti00_dir, name, length_m, duration_s):
    seq = load_kitti00(kitti00_dir, *WINDOWS[name], max_gt_rate_misfit_radps=None)  # paper_928m has defects
    assert abs(seq.path_length_m() - length_m) < 3.0
    assert abs(seq.frame_t_s[-1] - seq.frame_t_s[0] - duration_s) < 0.5


@pytest.mark.data
def test_frames_are_on_the_imu_clock_and_covered_by_imu(kitti00_dir, window540):
    times = np.loadtxt(kitti00_dir / TIMES_FILE)
    first, last = WINDOWS["paper_540m"]
    np.testing.assert_allclose(window540.frame_t_s, times[first:last + 1] + TIME_OFFSET_S)
    assert window540.imu.t_s[0] <= window540.frame_t_s[0] - 0.1
    assert window540.imu.t_s[-1] >= window540.frame_t_s[-1] + 0.1
    assert np.diff(window540.imu.t_s).max() < 0.05


@pytest.mark.data
def test_world_is_gravity_aligned_and_starts_at_the_first_frame(window540):
    gt = window540.truth
    np.testing.assert_allclose(gt.p_world_imu_m[0], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(gt.R_world_imu), 1.0, atol=1e-9)
    assert abs(np.linalg.norm(window540.gravity_world_mps2) - 9.81) < 0.02
    # Over 81 s the mean acceleration is dv/T; the IMU rotated to the world must match it.
    imu = window540.imu
    inside = (imu.t_s >= window540.frame_t_s[0]) & (imu.t_s <= window540.frame_t_s[-1])
    from scipy.spatial.transform import Rotation, Slerp

    R = Slerp(window540.frame_t_s, Rotation.from_matrix(gt.R_world_imu))(imu.t_s[inside]).as_matrix()
    f_world = np.einsum("nij,nj->ni", R, imu.accel_imu_mps2[inside]).mean(axis=0)
    a_mean = (gt.v_world_imu_mps[-1] - gt.v_world_imu_mps[0]) / (window540.frame_t_s[-1] - window540.frame_t_s[0])
    np.testing.assert_allclose(f_world + window540.gravity_world_mps2, a_mean, atol=0.05)
    # The IMU's x axis starts pointing along the world's x (horizontal), as documented.
    x_axis = gt.R_world_imu[0][:, 0]
    assert x_axis[0] > 0.99 and abs(x_axis[1]) < 1e-9


@pytest.mark.data
def test_velocity_is_the_derivative_of_position(window540):
    gt, t = window540.truth, window540.frame_t_s
    mid_v = np.diff(gt.p_world_imu_m, axis=0) / np.diff(t)[:, None]
    err = np.linalg.norm(0.5 * (gt.v_world_imu_mps[1:] + gt.v_world_imu_mps[:-1]) - mid_v, axis=1)
    # The GT positions jitter by centimetres, so the spline slope departs from chords a little.
    assert np.median(err) < 0.02 and np.percentile(err, 99) < 0.2 and err.max() < 0.5
    assert 6.0 < np.linalg.norm(gt.v_world_imu_mps, axis=1).mean() < 7.5


@pytest.mark.data
def test_gyro_rotated_into_gt_frame_matches_gt_rotation_rates(window540):
    gt, t = window540.truth, window540.frame_t_s
    R0, R1 = gt.R_world_imu[:-1], gt.R_world_imu[1:]
    w_gt_body = so3_log(np.swapaxes(R0, 1, 2) @ R1) / np.diff(t)[:, None]
    w_imu_body = _mean_rate(window540.imu, t[:-1], t[1:])
    # Rotating both by the GT attitude gives world-frame rates (the yaw rate is world z).
    w_gt = np.einsum("nij,nj->ni", R0, w_gt_body)
    w_imu = np.einsum("nij,nj->ni", R0, w_imu_body)
    corr_all = np.corrcoef(w_gt.ravel(), w_imu.ravel())[0, 1]
    corr_yaw = np.corrcoef(w_gt[:, 2], w_imu[:, 2])[0, 1]
    assert corr_all > 0.99 and corr_yaw > 0.99
    assert np.median(np.abs(w_gt - w_imu)) < 0.005


@pytest.mark.data
def test_integrating_one_second_of_imu_from_gt_lands_near_gt(window540):
    gt, t, imu, g = window540.truth, window540.frame_t_s, window540.imu, window540.gravity_world_mps2
    starts = np.arange(0, len(t) - 11, 10)
    R, p, v = gt.R_world_imu[starts].copy(), gt.p_world_imu_m[starts].copy(), gt.v_world_imu_mps[starts].copy()
    # All 1-s segments in lock-step: the same number of 10 ms steps, each from its own start time.
    steps = np.round((t[starts + 10] - t[starts]) / 0.01).astype(int)
    n_steps = steps.max()
    for j in range(n_steps):
        ts = t[starts] + np.minimum(j, steps) * 0.01
        dt = np.where(j < steps, np.minimum(0.01, t[starts + 10] - ts), 0.0)
        i = np.searchsorted(imu.t_s, ts, side="right") - 1
        a = np.einsum("nij,nj->ni", R, imu.accel_imu_mps2[i]) + g
        p = p + v * dt[:, None] + 0.5 * a * dt[:, None] ** 2
        v = v + a * dt[:, None]
        R = R @ so3_exp(imu.gyro_imu_radps[i] * dt[:, None])
    err = np.linalg.norm(p - gt.p_world_imu_m[starts + 10], axis=1)
    assert np.median(err) < 0.2
    assert np.percentile(err, 90) < 0.5
    assert err.max() < 1.0


@pytest.mark.data
def test_simulated_camera_uses_perturbed_truth_and_is_reproducible(kitti00_dir):
    pert = CalibrationPerturbation(d_intrinsics_px=(3.0, -2.0, 1.0, -4.0), d_rotvec_cam_rad=(0.0, 0.0, 0.01),
                                   d_p_imu_cam_m=(0.05, 0.0, -0.02))
    a = load_kitti00(kitti00_dir, 15, 120, camera="simulated", seed=7, truth_perturbation=pert, max_features=30)
    b = load_kitti00(kitti00_dir, 15, 120, camera="simulated", seed=7, truth_perturbation=pert, max_features=30)
    ref = kitti_2011_10_03_calibration(rectified=True)
    assert a.truth_calibration.fx_px[0] == ref.fx_px[0] + 3.0
    # rtol: KITTI's rectified R_cam_imu is orthonormal to 1.8e-7 only (7 printed digits)
    np.testing.assert_allclose(geodesic_angle_deg(ref.R_cam_imu[0], a.truth_calibration.R_cam_imu[0]),
                               np.degrees(0.01), rtol=1e-6)
    np.testing.assert_array_equal(a.tracks.uv_px, b.tracks.uv_px)
    assert a.tracks.n_features.min() > 10 and a.tracks.n_features.max() <= 30
    assert a.tracks.uv_px.shape[0] == a.n_frames - 2


@pytest.mark.data
def test_real_tracks_are_rectified_left_pixels_of_the_window(kitti00_dir):
    seq = load_kitti00(kitti00_dir, 15, 93, camera="real_tracks", max_features=None)
    assert seq.truth_calibration is None
    tr = seq.tracks
    assert tr.frame_index[0] == 2 and len(tr.frame_index) == seq.n_frames - 2
    assert tr.n_features.min() > 100
    uv = tr.uv_px[tr.valid]
    assert (uv[..., 0] >= 0).all() and (uv[..., 0] < 1241).all() and (uv[..., 1] < 376).all()
    # Real features move little between consecutive frames (a car at ~7 m/s, 10 Hz).
    assert np.median(np.linalg.norm(np.diff(uv, axis=1), axis=-1)) < 10.0
    capped = load_kitti00(kitti00_dir, 15, 93, camera="real_tracks", max_features=9)
    assert capped.tracks.n_features.max() == 9


@pytest.mark.data
def test_real_tracks_report_the_frames_the_file_lacks(kitti00_dir):
    seq = load_kitti00(kitti00_dir, 15, 153, camera="real_tracks", max_features=None)
    # The file has no rows for the even frames 94..130, so triplets ending in 94..132 are empty.
    assert seq.meta["triplets_without_tracks"] == list(range(94, 133))


@pytest.mark.data
@pytest.mark.parametrize("first, last, camera, match", [
    (5, 100, "simulated", r"IMU gap of 1\.920 s .*between frames 0 and 14"),
    (4000, 4600, "simulated", r"window frames 4000\.\.4600 outside"),
    (15, 200, "real_tracks", r"VO_stereo_factors00\.txt: real tracks exist for frames 15\.\.153"),
    (15, 100, "stereo", r"camera must be"),
])
def test_bad_requests_on_the_real_data_raise_naming_frames(kitti00_dir, first, last, camera, match):
    with pytest.raises(KittiDataError, match=match):
        load_kitti00(kitti00_dir, first, last, camera=camera)


# ---------------------------------------------------------------- synthetic folders


def _write_folder(path: Path, n_frames: int = 40, g_W=(0.0, 9.81, 0.0), accel=0.5) -> Path:
    """A tiny sequence-00-like folder: the camera moves along its z axis with constant
    acceleration; W is the camera frame of frame 0; the IMU (100 Hz) measures the matching
    specific force under gravity ``g_W``."""
    path.mkdir(parents=True, exist_ok=True)
    t = np.arange(n_frames) * 0.1
    T = np.tile(np.eye(4)[:3], (n_frames, 1, 1))
    T[:, 2, 3] = 5.0 * t + 0.5 * accel * t**2
    np.savetxt(path / GT_FILE, T.reshape(n_frames, 12), fmt="%.9e")
    np.savetxt(path / TIMES_FILE, t, fmt="%.9e")
    t_imu = np.arange(-50, n_frames * 10 + 50) * 0.01
    R_cam_imu, _ = T_cam_imu_2011_10_03(rectified=True)
    f = R_cam_imu.T @ (np.array([0.0, 0.0, accel]) - np.asarray(g_W))
    rows = np.column_stack([t_imu + TIME_OFFSET_S, np.full(len(t_imu), 0.01), np.tile(f, (len(t_imu), 1)),
                            np.zeros((len(t_imu), 3))])
    np.savetxt(path / IMU_FILE, rows, fmt="%.12f", header="Time dt accelX accelY accelZ omegaX omegaY omegaZ",
               comments="")
    (path / TRACKS_FILE).write_text("20 1 10 8 20 0 0 10\n21 1 11 9 21 0 0 10\n22 1 12 10 22 0 0 10\n")
    return path


def _replace_line(path: Path, line_no: int, text: str) -> None:
    lines = path.read_text().splitlines(keepends=True)
    lines[line_no - 1] = text + "\n"
    path.write_text("".join(lines))


def test_gravity_estimate_recovers_a_planted_tilted_gravity(tmp_path):
    g_W = 9.81 * np.array([0.03, 0.999, -0.02]) / np.linalg.norm([0.03, 0.999, -0.02])
    folder = _write_folder(tmp_path / "k", g_W=g_W)
    seq = load_kitti00(folder, 15, 39, camera="real_tracks")
    from avio.datasets.kitti00 import kitti00_truth

    np.testing.assert_allclose(kitti00_truth(folder).g_W_mps2, g_W, atol=1e-3)
    np.testing.assert_allclose(seq.gravity_world_mps2, [0, 0, -9.81], atol=1e-3)
    # The forward motion is horizontal in the gravity-aligned world only up to the planted tilt.
    direction = seq.truth.p_world_imu_m[-1] / np.linalg.norm(seq.truth.p_world_imu_m[-1])
    np.testing.assert_allclose(direction[2], -g_W[2] / 9.81, atol=1e-3)  # up = -g


def test_imu_poses_follow_the_rectified_extrinsic():
    R_cam_imu, t_cam_imu = T_cam_imu_2011_10_03(rectified=True)
    T = np.eye(4)[None].repeat(2, 0)
    T[1, :3, :3] = so3_exp(np.array([0.1, -0.2, 0.3]))
    T[1, :3, 3] = [1.0, 2.0, 3.0]
    R_W_imu, p_W_imu = imu_poses_in_gt_world(T)
    # A point fixed on the IMU maps to the same world point through either chain.
    x_imu = np.array([0.3, -0.1, 0.7])
    via_cam = T[:, :3, :3] @ (R_cam_imu @ x_imu + t_cam_imu) + T[:, :3, 3]
    np.testing.assert_allclose(np.einsum("nij,j->ni", R_W_imu, x_imu) + p_W_imu, via_cam, atol=1e-6)


def test_gravity_estimator_is_exact_on_constant_acceleration():
    t = np.arange(0, 301) * 0.01
    frames = t[::10]
    R = so3_exp(np.zeros((len(frames), 3)))
    g = np.array([0.1, 9.8, 0.2])
    a = np.array([0.3, 0.0, -0.1])
    imu = ImuSamples(t, np.tile(a - g, (len(t), 1)), np.zeros((len(t), 3)))
    v = np.outer(frames, a)
    np.testing.assert_allclose(estimate_gravity_gt_world(frames, R, v, imu), g, atol=1e-9)


def test_missing_file_is_named(tmp_path):
    folder = _write_folder(tmp_path / "k")
    (folder / IMU_FILE).unlink()
    with pytest.raises(KittiDataError, match=f"{IMU_FILE}: file not found"):
        load_kitti00(folder, 15, 30)


@pytest.mark.parametrize("file, line_no, text, match", [
    (GT_FILE, 7, "1 0 0 0 0 1 0 0 0 0 1", f"{GT_FILE}:7: expected 12 numbers, got 11"),
    (IMU_FILE, 12, "46535.0 0.01 0 0 9.8 0 0 zero", f"{IMU_FILE}:12: not a number"),
    (TIMES_FILE, 9, "1.0e-01", f"{TIMES_FILE}:9: time .* does not increase"),
    (IMU_FILE, 30, "46533.0 0.01 0 0 9.8 0 0 0", f"{IMU_FILE}:30: time .* does not increase"),
])
def test_malformed_lines_are_named_by_file_and_line(tmp_path, file, line_no, text, match):
    folder = _write_folder(tmp_path / "k")
    _replace_line(folder / file, line_no, text)
    with pytest.raises(KittiDataError, match=match):
        load_kitti00(folder, 15, 30)


def test_imu_gap_inside_window_names_the_frames(tmp_path):
    folder = _write_folder(tmp_path / "k")
    lines = (folder / IMU_FILE).read_text().splitlines(keepends=True)
    # IMU rows are 10 ms apart from -0.5 s; drop 2.05..2.35 s (between frames 20 and 24).
    keep = lines[:1 + 50 + 205] + lines[1 + 50 + 236:]
    (folder / IMU_FILE).write_text("".join(keep))
    with pytest.raises(KittiDataError, match=r"IMU gap of 0\.3.0 s .* between frames 20 and 24, inside the "
                                             r"requested frames 15\.\.30"):
        load_kitti00(folder, 15, 30)
    # A window that ends before the gap loads, and a wider limit accepts it.
    assert load_kitti00(folder, 15, 19, camera="real_tracks").n_frames == 5
    assert load_kitti00(folder, 15, 30, camera="real_tracks", max_imu_gap_s=0.5).n_frames == 16


def test_window_outside_the_data_is_an_error(tmp_path):
    folder = _write_folder(tmp_path / "k")
    with pytest.raises(KittiDataError, match=r"window frames 30\.\.45 outside the data \(frames 0\.\.39\)"):
        load_kitti00(folder, 30, 45)
    with pytest.raises(KittiDataError, match=r"need IMU over"):
        load_kitti00(folder, 15, 39, imu_margin_s=1.0)


def test_perturbation_zero_is_the_reference_and_rotation_angle_is_its_norm():
    ref = kitti_2011_10_03_calibration(rectified=True)
    same = CalibrationPerturbation().apply(ref)
    for name in ("fx_px", "cy_px", "R_cam_imu", "p_imu_cam_m", "time_offset_s"):
        np.testing.assert_array_equal(getattr(same, name), getattr(ref, name))
    rot = CalibrationPerturbation(d_rotvec_cam_rad=(0.01, -0.02, 0.005), time_offset_s=0.01).apply(ref)
    # rtol: KITTI's rectified R_cam_imu is orthonormal to 1.8e-7 only (7 printed digits)
    np.testing.assert_allclose(geodesic_angle_deg(ref.R_cam_imu, rot.R_cam_imu),
                               np.degrees(np.linalg.norm([0.01, -0.02, 0.005])), rtol=1e-6)
    assert rot.time_offset_s[0] == pytest.approx(0.01)


def test_memoised_parse_follows_file_changes(tmp_path):
    folder = _write_folder(tmp_path / "k")
    before = load_kitti00(folder, 15, 30, camera="real_tracks").path_length_m()
    gt = np.loadtxt(folder / GT_FILE)
    gt[:, 11] *= 2.0  # twice as far along z
    np.savetxt(folder / GT_FILE, gt, fmt="%.9e")
    after = load_kitti00(folder, 15, 30, camera="real_tracks").path_length_m()
    assert after == pytest.approx(2.0 * before, rel=1e-6)


def test_content_hash_identifies_the_window(tmp_path):
    folder = _write_folder(tmp_path / "k")
    a = load_kitti00(folder, 15, 30, camera="real_tracks", seed=1)
    b = load_kitti00(folder, 15, 30, camera="real_tracks", seed=1)
    c = load_kitti00(folder, 15, 31, camera="real_tracks", seed=1)
    assert a.meta["content_hash"] == b.meta["content_hash"] != c.meta["content_hash"]


@pytest.mark.data
def test_gravity_estimates_from_thirds_of_the_drive_agree(kitti00_dir):
    from avio.datasets.kitti00 import kitti00_truth, read_kitti00

    raw, truth = read_kitti00(kitti00_dir), kitti00_truth(kitti00_dir)
    thirds = [(15, 1500), (1500, 3000), (3000, 4540)]
    g = np.array([estimate_gravity_gt_world(raw.frame_t_s[a:b], truth.R_W_imu[a:b], truth.v_W_imu_mps[a:b],
                                            raw.imu) for a, b in thirds])
    cos = g @ truth.g_W_mps2 / np.linalg.norm(g, axis=1) / np.linalg.norm(truth.g_W_mps2)
    assert np.degrees(np.arccos(np.minimum(cos, 1.0))).max() < 0.1
    assert np.abs(np.linalg.norm(g, axis=1) - 9.81).max() < 0.02


def test_perturbation_may_come_as_a_plain_mapping(tmp_path):
    folder = _write_folder(tmp_path / "k")
    seq = load_kitti00(folder, 15, 30, truth_perturbation={"d_intrinsics_px": (1.0, 0.0, 0.0, 0.0)})
    assert seq.truth_calibration.fx_px[0] == pytest.approx(718.856 + 1.0)
    assert seq.meta["truth_perturbation"]["d_intrinsics_px"] == (1.0, 0.0, 0.0, 0.0)
    assert seq.tracks.uv_px.shape[0] == seq.n_frames - 2


@pytest.mark.data
def test_windows_whose_ground_truth_contradicts_the_gyro_are_refused_naming_the_frames(kitti00_dir):
    from avio.datasets.kitti00 import KittiDataError, ground_truth_rate_misfit, kitti00_truth, read_kitti00

    with pytest.raises(KittiDataError, match=r"frames 2404\.\.3553: .*2676-2692.*2964-2980"):
        load_kitti00(kitti00_dir, *WINDOWS["paper_928m"])
    raw, truth = read_kitti00(kitti00_dir), kitti00_truth(kitti00_dir)
    for name in ("paper_540m", "clean_928m"):
        _, rms = ground_truth_rate_misfit(raw, truth, *WINDOWS[name])
        assert rms.max() < 0.02, name
    seq = load_kitti00(kitti00_dir, *WINDOWS["clean_928m"], max_features=10)
    assert abs(seq.path_length_m() - 929.0) < 3.0
