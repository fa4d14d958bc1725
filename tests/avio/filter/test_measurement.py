"""Trifocal measurement model: zero residual at the truth, Jacobians against finite differences."""

import copy

import numpy as np
import pytest
from filter_model import State, inject_correction, measurement_model, relative_poses, triplet_residuals
from test_filter import make_circle_sequence, perturbed

from avio.filter.config import FilterConfig
from avio.geometry import so3_exp


def _triplet(rng, n=3, F=6, noise_px=1.0):
    fx = np.array([700.0, 720, 710])[:n]
    fy = np.array([705.0, 715, 718])[:n]
    cx = np.array([600.0, 610, 605])[:n]
    cy = np.array([180.0, 185, 190])[:n]
    Rc = so3_exp(rng.normal(0, 0.05, (3, n, 3)))
    pc = np.stack([np.zeros((n, 3)), np.array([0.3, 0.05, 1.0]) + rng.normal(0, 0.05, (n, 3)),
                   np.array([0.6, 0.1, 2.0]) + rng.normal(0, 0.05, (n, 3))])
    Xw = np.c_[rng.uniform(-12, 12, F), rng.uniform(-3, 3, F), rng.uniform(8, 30, F)]
    K = np.array([[fx[0], 0, cx[0]], [0, fy[0], cy[0]], [0, 0, 1]])
    uv = np.zeros((F, 3, 2))
    for i in range(3):
        m = ((Xw - pc[i, 0]) @ Rc[i, 0]) @ K.T
        uv[:, i] = m[:, :2] / m[:, 2:]
    uv_clean = uv.copy()
    uv += rng.normal(0, noise_px, uv.shape)
    return (fx, fy, cx, cy), Rc, pc, uv, uv_clean


def test_residuals_vanish_at_the_truth():
    intr, Rc, pc, _, uv = _triplet(np.random.default_rng(0), n=1, noise_px=0.0)
    r, _ = triplet_residuals(uv, *relative_poses(Rc, pc), *intr)
    assert np.abs(r).max() < 1e-6


def test_triplet_jacobian_matches_finite_differences():
    intr, Rc, pc, uv, _ = _triplet(np.random.default_rng(1))
    R12, t12, R13, t13 = relative_poses(Rc, pc)
    r, J = triplet_residuals(uv, R12, t12, R13, t13, *intr)

    def f(d):
        return triplet_residuals(uv, R12 @ so3_exp(d[0:3]), t12 + d[3:6], R13 @ so3_exp(d[6:9]),
                                 t13 + d[9:12], *intr)[0]

    eps = 1e-6
    # Innovations r = z - h, so dr/dd = -J.
    J_fd = np.stack([-(f(eps * e) - f(-eps * e)) / (2 * eps) for e in np.eye(12)], axis=-1)
    scale = np.abs(J_fd).max(axis=(0, 1, 3), keepdims=True) + 1e-12
    assert np.abs((J - J_fd) / scale).max() < 1e-5


def test_the_filter_path_without_the_unused_sampson_distance_keeps_the_other_rows():
    # avio/filter/update.py measures with pair23=False (the update uses residuals 0, 2, 3): the other
    # rows must be the very same bits, and row 1 zero.
    from avio.filter.trifocal import feature_residuals, rot_t

    intr, Rc, pc, uv, _ = _triplet(np.random.default_rng(5), n=1)
    R12, t12, R13, t13 = (a[0] for a in relative_poses(Rc, pc))
    R23 = R12.T @ R13
    t23 = rot_t(R12, tuple(t13 - t12))
    fx, fy, cx, cy = (float(a[0]) for a in intr)
    out = {}
    for pair23 in (True, False):
        r, J, G = np.full((len(uv), 4), np.nan), np.full((len(uv), 4, 12), np.nan), np.full((len(uv), 4, 6), np.nan)
        for f in range(len(uv)):
            feature_residuals(uv[f], R12, tuple(t12), R13, tuple(t13), R23, t23, fx, fy, cx, cy, r[f], J[f], G[f],
                              pair23)
        out[pair23] = r, J, G
    for full, lean in zip(out[True], out[False]):
        np.testing.assert_array_equal(lean[:, [0, 2, 3]], full[:, [0, 2, 3]])
        assert np.all(lean[:, 1] == 0.0)
    assert np.all(out[True][0][:, 1] != 0.0)  # noisy pixels: the full path does compute r1


def test_pixel_jacobian_matches_finite_differences():
    # G = d r / d pixels at the exact (zero-residual) geometry, where the Sampson distance is
    # a first-order distance: its pixel gradient has unit norm there.
    intr, Rc, pc, _, uv = _triplet(np.random.default_rng(2), n=1, noise_px=0.0)
    poses = relative_poses(Rc, pc)
    r, _, G = triplet_residuals(uv, *poses, *intr, with_pixel_jacobian=True)
    eps = 1e-4
    cols = []
    for img in range(3):
        for axis in range(2):
            d = np.zeros_like(uv)
            d[:, img, axis] = eps
            cols.append((triplet_residuals(uv + d, *poses, *intr)[0] - triplet_residuals(uv - d, *poses, *intr)[0])
                        / (2 * eps))
    G_fd = np.stack(cols, axis=-1)  # (n, F, 4, 6)
    assert np.abs(G - G_fd).max() < 1e-4 * max(1.0, np.abs(G_fd).max())
    assert np.allclose(np.linalg.norm(G[..., :2, :], axis=-1), 1.0, atol=1e-9)


def test_residual_covariance_from_pixel_noise_matches_monte_carlo():
    # sigma^2 G G^T is the covariance of the residuals under pixel noise (small noise, first order).
    intr, Rc, pc, _, uv = _triplet(np.random.default_rng(3), n=1, F=4, noise_px=0.0)
    poses = relative_poses(Rc, pc)
    _, _, G = triplet_residuals(uv, *poses, *intr, with_pixel_jacobian=True)
    sigma, rng = 0.05, np.random.default_rng(4)
    draws = np.stack([triplet_residuals(uv + rng.normal(0, sigma, uv.shape), *poses, *intr)[0][0]
                      for _ in range(4000)])  # (m, F, 4)
    for f in range(uv.shape[0]):
        predicted = sigma**2 * G[0, f] @ G[0, f].T
        measured = np.cov(draws[:, f].T)
        assert np.allclose(measured, predicted, rtol=0.12, atol=0.12 * np.abs(predicted).max())


@pytest.mark.parametrize("time_offset", [False, True])
def test_state_jacobian_matches_finite_differences(time_offset):
    seq = make_circle_sequence(n_frames=20, pixel_noise_px=1.0)
    cal = perturbed(seq.truth_calibration, 2, seed=1)
    if not time_offset:
        cal.time_offset_s[:] = 0.0
    rng = np.random.default_rng(0)
    st = State(seq, 2, FilterConfig())
    tr, k = seq.truth, 10
    st.p = tr.p_world_imu_m[[k, k]] + rng.normal(0, 0.1, (2, 3))
    st.R = tr.R_world_imu[[k, k]] @ so3_exp(rng.normal(0, 0.01, (2, 3)))
    st.v = tr.v_world_imu_mps[[k, k]]
    st.bg = rng.normal(0, 0.01, (2, 3))
    for i in range(2):
        st.cp[i] = tr.p_world_imu_m[[k - 2 + i] * 2] + rng.normal(0, 0.1, (2, 3))
        st.cR[i] = tr.R_world_imu[[k - 2 + i] * 2] @ so3_exp(rng.normal(0, 0.01, (2, 3)))
    uv = seq.tracks.uv_px[k - 2][seq.tracks.valid[k - 2]][:6]
    gyro = rng.normal(0, 0.2, (2, 3)) + st.bg
    r, J, C, _, _ = measurement_model(st, cal, uv, gyro - st.bg, cal.time_offset_s)
    H = J @ C[:, None]

    def residual(dx):
        s2 = copy.deepcopy(st)
        inject_correction(s2, dx)
        return measurement_model(s2, cal, uv, gyro - s2.bg, cal.time_offset_s)[0]

    eps = 1e-6
    H_fd = np.stack([-(residual(eps * np.tile(e, (2, 1))) - residual(-eps * np.tile(e, (2, 1)))) / (2 * eps)
                     for e in np.eye(27)], axis=-1)
    scale = np.abs(H_fd).max() + 1e-12
    pose_cols = np.r_[0:9, 15:27]
    assert np.abs(H - H_fd)[..., pose_cols].max() / scale < 1e-5
    # The gyro-bias column goes through the first-order time shift exp((w - b_g) td): exact to O(td).
    assert np.abs(H - H_fd)[..., 12:15].max() / scale < (1e-3 if time_offset else 1e-9)
    assert np.all(H[..., 9:12] == 0.0)


def _transfer_gain(G):
    """Largest standard deviation of the transfer per pixel of noise: sqrt of diag(G G^T)."""
    return np.sqrt(np.einsum("...ac,...ac->...a", G[..., 2:4, :], G[..., 2:4, :])).max(axis=-1)


def test_a_middle_image_outlier_near_the_epipole_makes_a_degenerate_transfer():
    """An outlier in image 2 can put the line through m2 through the epipole: the transfer's
    noise gain explodes (the filter rejects gains above FilterConfig.max_transfer_gain) while
    inliers stay near 1-5."""
    from avio.filter.config import FilterConfig

    intr, Rc, pc, _, uv = _triplet(np.random.default_rng(5), n=1, F=8, noise_px=0.0)
    poses = relative_poses(Rc, pc)
    _, _, G = triplet_residuals(uv, *poses, *intr, with_pixel_jacobian=True)
    assert _transfer_gain(G).max() < 10.0
    worst = 0.0
    for du in np.linspace(-400, 400, 161):
        for dv in np.linspace(-150, 150, 61):
            bad = uv[:1].copy()
            bad[0, 1] += (du, dv)
            _, _, Gb = triplet_residuals(bad, *poses, *intr, with_pixel_jacobian=True)
            worst = max(worst, float(_transfer_gain(Gb).max()))
    assert worst > 10 * FilterConfig().max_transfer_gain
