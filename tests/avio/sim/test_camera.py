import numpy as np
import pytest
from scipy.spatial import cKDTree

from avio.calibration import Calibration
from avio.geometry import geodesic_angle_deg
from avio.reference import IMAGE_SIZE_PX, kitti_2011_10_03_calibration
from avio.sim.camera import (
    CameraSimError,
    camera_poses,
    corrupt_triplets,
    interpolate_pose,
    make_landmarks,
    project_landmarks,
    simulate_tracks,
)
from avio.sim.trajectory import make_trajectory

FRAME_T = np.arange(0.0, 30.0 + 1e-9, 0.1)


@pytest.fixture(scope="module")
def world():
    traj = make_trajectory("city_hills", 30.0, 7.0, seed=4)
    truth = traj.ground_truth(FRAME_T)
    landmarks = make_landmarks(truth, np.random.default_rng(1))
    return traj, truth, landmarks


def _with_offset(cal: Calibration, offset_s: float) -> Calibration:
    return Calibration.single(
        cal.fx_px[0], cal.fy_px[0], cal.cx_px[0], cal.cy_px[0], cal.R_cam_imu[0], cal.p_imu_cam_m[0], offset_s
    )


def _project_by_hand(truth, k, cal, X):
    """Pinhole projection of world points X (n, 3) into frame k, written out independently."""
    R_wi, p_wi = truth.R_world_imu[k], truth.p_world_imu_m[k]
    R_ci, p_ic = cal.R_cam_imu[0], cal.p_imu_cam_m[0]
    # world -> imu -> camera
    x_imu = (X - p_wi) @ R_wi  # R_wi^T (X - p)
    x_cam = (x_imu - p_ic) @ R_ci.T
    return np.c_[cal.fx_px[0] * x_cam[:, 0] / x_cam[:, 2] + cal.cx_px[0],
                 cal.fy_px[0] * x_cam[:, 1] / x_cam[:, 2] + cal.cy_px[0]]


def test_noiseless_tracks_reproject_exactly_from_the_truth_calibration(world):
    traj, truth, landmarks = world
    cal = kitti_2011_10_03_calibration()
    tracks, det = simulate_tracks(
        truth, FRAME_T, cal, landmarks, IMAGE_SIZE_PX, 0.0, 0.0, 30, np.random.default_rng(0), return_details=True
    )
    t_idx, f_idx = np.nonzero(tracks.valid)
    lm = det["landmark_id"][t_idx, f_idx]
    for j in range(3):
        for k in np.unique(tracks.frame_index[t_idx] - 2 + j)[::7]:
            sel = tracks.frame_index[t_idx] - 2 + j == k
            expected = _project_by_hand(truth, k, cal, landmarks[lm[sel]])
            np.testing.assert_allclose(tracks.uv_px[t_idx[sel], f_idx[sel], j], expected, atol=1e-8)
    np.testing.assert_array_equal(det["uv_true_px"], tracks.uv_px)


def test_projections_lie_in_the_image_and_in_front(world):
    _, truth, landmarks = world
    obs = project_landmarks(truth, FRAME_T, kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX, 1.0, 80.0)
    assert obs.depth_m.min() > 1.0 and obs.depth_m.max() <= 80.0
    assert obs.uv_px.min() >= 0.0
    assert obs.uv_px[:, 0].max() <= IMAGE_SIZE_PX[0] - 1 and obs.uv_px[:, 1].max() <= IMAGE_SIZE_PX[1] - 1
    per_frame = np.bincount(obs.frame_index, minlength=len(FRAME_T))
    assert per_frame.min() >= 60, "a street view should show many landmarks in every frame"


def test_pixel_noise_and_outliers_have_the_requested_sizes(world):
    _, truth, landmarks = world
    tracks, det = simulate_tracks(
        truth, FRAME_T, kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX, 0.8, 0.1, 30,
        np.random.default_rng(2), return_details=True,
    )
    err = tracks.uv_px - det["uv_true_px"]
    inlier = tracks.valid & ~det["outlier"]
    assert np.std(err[inlier]) == pytest.approx(0.8, rel=0.05)
    assert det["outlier"].sum() / tracks.valid.sum() == pytest.approx(0.1, abs=0.015)
    jump = np.linalg.norm(err[det["outlier"]], axis=-1)  # (n_outliers, 3)
    assert np.all((jump > 15).sum(axis=1) == 1), "an outlier jumps in exactly one image"
    assert jump.max() < 60 + 5 * 0.8


def _noise_of_shared_images(tracks, det):
    """The pixel noise of the two images consecutive triplets share, for every feature seen in
    both: (n, 2, 2) from the earlier triplet and the same (n, 2, 2) from the later one."""
    err = tracks.uv_px - det["uv_true_px"]
    earlier, later = [], []
    for t in np.nonzero(np.diff(tracks.frame_index) == 1)[0]:
        ids_next = det["landmark_id"][t + 1]
        for f in np.nonzero(tracks.valid[t])[0]:
            g = np.nonzero(tracks.valid[t + 1] & (ids_next == det["landmark_id"][t, f]))[0]
            if len(g):
                earlier.append(err[t, f, 1:])
                later.append(err[t + 1, g[0], :2])
    return np.array(earlier), np.array(later)


def test_pixel_noise_is_per_observation_unless_drawn_per_triplet(world):
    _, truth, landmarks = world
    shared, fresh = (
        simulate_tracks(truth, FRAME_T, kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX, 0.8, 0.0, 30,
                        np.random.default_rng(2), return_details=True, noise_per_triplet=per_triplet)
        for per_triplet in (False, True)
    )
    a, b = _noise_of_shared_images(*shared)
    assert len(a) > 500
    np.testing.assert_array_equal(a, b)  # one observation, one noise, in every triplet that uses it
    a, b = _noise_of_shared_images(*fresh)
    assert len(a) > 500
    assert np.std(a) == pytest.approx(0.8, rel=0.05) and np.std(b) == pytest.approx(0.8, rel=0.05)
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.05  # drawn afresh for every triplet


def test_corrupt_triplets_rejects_bad_fraction(world):
    _, truth, landmarks = world
    tracks = simulate_tracks(truth, FRAME_T, kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX,
                             0.0, 0.0, 10, np.random.default_rng(0))
    with pytest.raises(CameraSimError, match="outlier_fraction"):
        corrupt_triplets(tracks, 1.5, np.random.default_rng(0))


def test_tracks_per_triplet_reach_max_features(world):
    _, truth, landmarks = world
    tracks = simulate_tracks(truth, FRAME_T, kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX,
                             0.5, 0.05, 30, np.random.default_rng(3))
    assert tracks.uv_px.shape == (len(FRAME_T) - 2, 30, 3, 2)
    assert np.mean(tracks.n_features == 30) > 0.95


def test_reference_camera_looks_forward_from_above_the_imu(world):
    _, truth, _ = world
    R_wc, p_wc = camera_poses(truth, FRAME_T, kitti_2011_10_03_calibration())
    forward = truth.R_world_imu[:, :, 0]
    assert np.all(np.einsum("ni,ni->n", R_wc[:, :, 2], forward) > np.cos(np.radians(3.0)))
    up_m = np.einsum("ni,ni->n", p_wc - truth.p_world_imu_m, truth.R_world_imu[:, :, 2])
    np.testing.assert_allclose(up_m, 0.7461, atol=0.01)  # Table 1 tz


def test_time_offset_sees_the_world_at_the_shifted_time(world):
    traj, truth, landmarks = world
    cal = kitti_2011_10_03_calibration()
    shifted = _with_offset(cal, 0.04)
    exact_shift = project_landmarks(traj, FRAME_T[5:-5] + 0.04, cal, landmarks, IMAGE_SIZE_PX)
    via_offset = project_landmarks(traj, FRAME_T[5:-5], shifted, landmarks, IMAGE_SIZE_PX)
    np.testing.assert_array_equal(exact_shift.landmark_id, via_offset.landmark_id)
    np.testing.assert_allclose(exact_shift.uv_px, via_offset.uv_px, atol=1e-9)
    # A GroundTruth at the frames (as KITTI gives) is interpolated: close to the exact poses.
    interp = project_landmarks(truth, FRAME_T, shifted, landmarks, IMAGE_SIZE_PX, 5.0, 60.0)
    exact = project_landmarks(traj, FRAME_T, shifted, landmarks, IMAGE_SIZE_PX, 5.0, 60.0)
    common = np.intersect1d(interp.frame_index * 10**6 + interp.landmark_id, exact.frame_index * 10**6 + exact.landmark_id)
    a = interp.uv_px[np.isin(interp.frame_index * 10**6 + interp.landmark_id, common)]
    b = exact.uv_px[np.isin(exact.frame_index * 10**6 + exact.landmark_id, common)]
    assert np.median(np.linalg.norm(a - b, axis=1)) < 0.01
    assert np.max(np.linalg.norm(a - b, axis=1)) < 0.5


def test_interpolated_pose_matches_the_exact_trajectory_between_frames(world):
    traj, truth, _ = world
    t = FRAME_T[1:-1] + 0.037
    R, p = interpolate_pose(truth, FRAME_T, t)
    st = traj(t)
    assert np.abs(p - st.p_world_imu_m).max() < 1e-4
    assert geodesic_angle_deg(R, st.R_world_imu).max() < 0.01


def test_landmarks_line_the_street_and_clear_the_path(world):
    _, truth, landmarks = world
    d_path, nearest = cKDTree(truth.p_world_imu_m[:, :2]).query(landmarks[:, :2])
    assert d_path.min() >= 4.0 - 1e-9
    beside = nearest < len(truth.p_world_imu_m) - 1  # not in the 80 m extension past the end
    assert d_path[beside].max() <= 60.5  # lateral offsets are at most 60 m (+ frame spacing)
    again = make_landmarks(truth, np.random.default_rng(1))
    np.testing.assert_array_equal(again, landmarks)
    assert len(landmarks) > 2.5 * 210  # ~4 per metre over ~210 m + 80 m ahead, minus the cleared ones


def test_bad_inputs_raise():
    traj = make_trajectory("straight", 5.0, 5.0, seed=0)
    cal = kitti_2011_10_03_calibration()
    with pytest.raises(CameraSimError, match="batch of 1"):
        camera_poses(traj, FRAME_T[:10], Calibration.stack([cal, cal]))
    with pytest.raises(CameraSimError, match=r"\(n_lm, 3\)"):
        project_landmarks(traj, FRAME_T[:10], cal, np.zeros((4, 2)), IMAGE_SIZE_PX)
