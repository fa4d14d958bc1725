from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from avio.reference import IMAGE_SIZE_PX, kitti_2011_10_03_calibration
from avio.sim.camera import make_landmarks
from avio.sim.render import RenderError, load_projections, render_frames, render_image
from avio.sim.trajectory import make_trajectory

FRAME_T = np.arange(0.0, 0.5 + 1e-9, 0.1)


@pytest.fixture(scope="module")
def scene():
    traj = make_trajectory("city", 10.0, 7.0, seed=3)
    landmarks = make_landmarks(traj.ground_truth(np.arange(0, 10.01, 0.1)), np.random.default_rng(0))
    return traj, landmarks


def _centroid(image, uv, radius):
    u0, v0 = np.round(uv).astype(int)
    win = image[v0 - radius : v0 + radius + 1, u0 - radius : u0 + radius + 1]
    vv, uu = np.mgrid[v0 - radius : v0 + radius + 1, u0 - radius : u0 + radius + 1]
    return np.array([(win * uu).sum(), (win * vv).sum()]) / win.sum()


@pytest.mark.parametrize("sigma", [1.0, 2.0, 3.0])
def test_a_blob_is_centred_on_its_subpixel_position(sigma):
    uv = np.array([[100.37, 50.81]])
    image = render_image(uv, np.array([sigma]), np.array([150.0]), (200, 100), background_dn=0.0)
    np.testing.assert_allclose(_centroid(image, uv[0], int(np.ceil(4 * sigma))), uv[0], atol=1e-3)  # 4-sigma cut
    assert image.max() == pytest.approx(150.0 * (1 if sigma > 1.5 else 0.85), rel=0.12)
    quantised = np.round(image)
    np.testing.assert_allclose(_centroid(quantised, uv[0], int(np.ceil(4 * sigma))), uv[0], atol=0.05)


def test_each_landmark_renders_at_its_true_projection(scene, tmp_path):
    traj, landmarks = scene
    cal = kitti_2011_10_03_calibration()
    # Without the concentric halo (which only widens the support), so isolation is easy to judge.
    paths = render_frames(traj, FRAME_T, cal, landmarks, IMAGE_SIZE_PX, tmp_path, np.random.default_rng(1),
                          noise_dn=0.0, background_dn=40.0, halo_ratio=0.0)
    obs, sigma = load_projections(tmp_path)
    errors = []
    for k, path in enumerate(paths):
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED).astype(float) - 40.0
        assert image.shape == (IMAGE_SIZE_PX[1], IMAGE_SIZE_PX[0])
        sel = obs.frame_index == k
        uv, sg = obs.uv_px[sel], sigma[sel]
        # Isolated blobs away from the border: no other blob's 4-sigma support reaches the window.
        nearest = cKDTree(uv).query(uv, k=2)[0][:, 1]
        r = 12
        ok = (nearest > 2 * r + 1) & (uv[:, 0] > r) & (uv[:, 0] < IMAGE_SIZE_PX[0] - r - 1) & (uv[:, 1] > r) & (
            uv[:, 1] < IMAGE_SIZE_PX[1] - r - 1)
        errors += [np.linalg.norm(_centroid(image, uv[i], int(np.ceil(4 * sg[i]))) - uv[i]) for i in np.nonzero(ok)[0]]
    assert len(errors) > 50
    assert max(errors) < 0.2


def test_klt_tracks_rendered_frames_to_the_true_motion(scene, tmp_path):
    traj, landmarks = scene
    paths = render_frames(traj, FRAME_T[:2], kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX, tmp_path,
                          np.random.default_rng(2))
    obs, _ = load_projections(tmp_path)
    a, b = (cv2.imread(p, cv2.IMREAD_GRAYSCALE) for p in paths)
    in0, in1 = obs.frame_index == 0, obs.frame_index == 1
    both = np.intersect1d(obs.landmark_id[in0], obs.landmark_id[in1])
    uv0 = obs.uv_px[in0][np.isin(obs.landmark_id[in0], both)]
    uv1 = obs.uv_px[in1][np.isin(obs.landmark_id[in1], both)]
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(a, b, uv0.astype(np.float32), None, winSize=(21, 21), maxLevel=3)
    err = np.linalg.norm(tracked - uv1, axis=1)[status[:, 0] == 1]
    assert len(err) > 100
    assert np.median(err) < 0.5


def test_blob_and_halo_centroid_is_the_projection_in_a_full_render(scene, tmp_path):
    traj, landmarks = scene
    sparse = landmarks[::15]  # so that some halos stand alone
    paths = render_frames(traj, FRAME_T[:2], kitti_2011_10_03_calibration(), sparse, IMAGE_SIZE_PX, tmp_path,
                          np.random.default_rng(1), noise_dn=0.0, background_dn=40.0)
    obs, sigma = load_projections(tmp_path)
    errors = []
    for k, path in enumerate(paths):
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED).astype(float) - 40.0
        sel = obs.frame_index == k
        uv, r = obs.uv_px[sel], np.ceil(4 * 4.0 * sigma[sel]).astype(int)  # the halo's 4-sigma support
        dist, idx = cKDTree(uv).query(uv, k=len(uv))
        clear = np.all((dist[:, 1:] > (r[:, None] + r[idx[:, 1:]])), axis=1)
        ok = clear & (uv[:, 0] > r) & (uv[:, 0] < IMAGE_SIZE_PX[0] - r - 1) & (uv[:, 1] > r) & (
            uv[:, 1] < IMAGE_SIZE_PX[1] - r - 1)
        errors += [np.linalg.norm(_centroid(image, uv[i], r[i]) - uv[i]) for i in np.nonzero(ok)[0]]
    assert len(errors) >= 3
    assert max(errors) < 0.2


def test_a_complete_render_is_reused_and_a_bad_folder_fails_clearly(scene, tmp_path):
    traj, landmarks = scene
    args = (traj, FRAME_T[:3], kitti_2011_10_03_calibration(), landmarks, IMAGE_SIZE_PX, tmp_path)
    paths = render_frames(*args, np.random.default_rng(0))
    stamp = [Path(p).stat().st_mtime_ns for p in paths]
    assert render_frames(*args, np.random.default_rng(9)) == paths
    assert [Path(p).stat().st_mtime_ns for p in paths] == stamp
    Path(paths[1]).unlink()  # an incomplete folder is rendered again
    assert Path(render_frames(*args, np.random.default_rng(0))[1]).exists()
    (tmp_path / "projections.npz").write_bytes(b"not an npz")
    with pytest.raises(RenderError, match="projections.npz"):
        load_projections(tmp_path)
