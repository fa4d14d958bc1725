import numpy as np
import pytest

from avio.filter.config import FilterResult
from avio.geometry import so3_exp
from avio.metrics import MetricsError, drift_metrics, pose_errors, position_rmse_objective, segment_lengths_m
from avio.sequence import GroundTruth


def _truth(N=50, seed=0):
    rng = np.random.default_rng(seed)
    return GroundTruth(np.cumsum(rng.normal(0, 1, (N, 3)), 0), so3_exp(rng.normal(0, 1, (N, 3))),
                       rng.normal(0, 5, (N, 3)))


def _result(p, R, v, diverged_at=None):
    n, N = p.shape[:2]
    div_at = np.full(n, -1) if diverged_at is None else np.asarray(diverged_at)
    z = np.zeros((n, N), int)
    return FilterResult(p, R, v, div_at >= 0, div_at, z, z, np.zeros((n, N, 15)), np.zeros((n, N, 3)),
                        np.zeros((n, N, 3)))


def test_errors_match_hand_computation():
    truth = _truth()
    N = len(truth.p_world_imu_m)
    rng = np.random.default_rng(1)
    dp = rng.normal(0, 0.5, (2, N, 3))
    angle = np.array([0.01, 0.03])  # rad, about a fixed axis
    R = truth.R_world_imu[None] @ so3_exp(angle[:, None] * np.array([0.0, 0.6, 0.8]))[:, None]
    res = _result(truth.p_world_imu_m[None] + dp, R, truth.v_world_imu_mps[None] + 2 * dp)
    e = pose_errors(res, truth)
    d = np.linalg.norm(dp, axis=-1)
    np.testing.assert_allclose(e["position_rmse"], np.sqrt((d**2).mean(1)))
    np.testing.assert_allclose(e["position_mean"], d.mean(1))
    np.testing.assert_allclose(e["position_std"], d.std(1))
    np.testing.assert_allclose(e["velocity_rmse"], 2 * np.sqrt((d**2).mean(1)))
    np.testing.assert_allclose(e["attitude_errors"], np.degrees(angle)[:, None].repeat(N, 1), atol=1e-6)
    np.testing.assert_allclose(position_rmse_objective(res, truth), e["position_rmse"])
    # RMSE^2 = mean^2 + std^2 (population std), the relation Tables 2-3 obey.
    np.testing.assert_allclose(e["position_rmse"] ** 2, e["position_mean"] ** 2 + e["position_std"] ** 2)


def test_diverged_filters_get_a_finite_ordered_penalty():
    truth = _truth()
    N = len(truth.p_world_imu_m)
    p = np.repeat(truth.p_world_imu_m[None], 3, 0)
    R = np.repeat(truth.R_world_imu[None], 3, 0)
    v = np.repeat(truth.v_world_imu_mps[None], 3, 0)
    res = _result(p, R, v, diverged_at=[-1, 10, 40])
    f = position_rmse_objective(res, truth, divergence_penalty_m=500.0)
    assert f[0] == 0.0
    assert np.all(np.isfinite(f)) and f[1] > f[2] >= 500.0
    np.testing.assert_allclose(f[1], 500.0 * (2 - 10 / N))


def test_shape_mismatch_is_an_error():
    truth = _truth()
    res = _result(np.zeros((1, 3, 3)), np.zeros((1, 3, 3, 3)), np.zeros((1, 3, 3)))
    with pytest.raises(MetricsError):
        pose_errors(res, truth)


# --- drift metrics: hand-computed cases on a straight 300 m drive at 1 m per frame ----------

def _line(N=301, step=1.0):
    p = np.zeros((N, 3))
    p[:, 0] = step * np.arange(N)
    R = np.repeat(np.eye(3)[None], N, 0)
    return GroundTruth(p, R, np.zeros((N, 3)))


def test_segment_lengths_follow_the_documented_rule():
    lengths, kitti = segment_lengths_m(540.0)
    assert kitti and lengths.tolist() == [100, 200, 300, 400, 500]
    lengths, kitti = segment_lengths_m(928.0)
    assert kitti and lengths.tolist() == [100, 200, 300, 400, 500, 600, 700, 800]
    lengths, kitti = segment_lengths_m(63.0)
    assert not kitti and lengths.tolist() == [10, 20, 30, 40, 50, 60]
    assert segment_lengths_m(60.0)[0].tolist() == [10, 20, 30, 40, 50]
    assert segment_lengths_m(4.7)[0].tolist() == [1, 2, 3, 4]  # a room-sized flight: 1 m steps
    assert segment_lengths_m(1.0)[0].size == 0


def test_scale_drift_gives_the_hand_computed_t_rel():
    truth = _line()
    p = 1.01 * truth.p_world_imu_m[None]  # 1 % too long everywhere
    d = drift_metrics(p, truth.R_world_imu[None], truth)
    # starts every 10 frames; a segment of L m ends at the first frame more than L m on: L + 1 m.
    # L = 100: starts 0..190 (20 segments), L = 200: starts 0..90 (10); error 0.01 (L + 1) m.
    per_metre = (20 * 0.01 * 101 / 100 + 10 * 0.01 * 201 / 200) / 30
    np.testing.assert_allclose(d["t_rel_pct"], [100 * per_metre])
    np.testing.assert_allclose(d["drift_m_per_m"], [per_metre])
    np.testing.assert_allclose(d["r_rel_deg_per_100m"], [0.0], atol=1e-12)
    np.testing.assert_allclose(d["max_jump_m"], [0.01])


def test_constant_yaw_rate_error_gives_the_hand_computed_r_rel():
    truth = _line()
    N = len(truth.p_world_imu_m)
    rate = 0.002  # deg per frame about z
    R = so3_exp(np.radians(rate * np.arange(N))[:, None] * np.array([0.0, 0.0, 1.0]))
    d = drift_metrics(truth.p_world_imu_m[None], R[None], truth)
    # the rotation error of a segment is rate * (L + 1) deg
    expected = (20 * 100 * rate * 101 / 100 + 10 * 100 * rate * 201 / 200) / 30
    np.testing.assert_allclose(d["r_rel_deg_per_100m"], [expected], rtol=1e-9)
    np.testing.assert_allclose(d["max_jump_m"], [0.0], atol=1e-12)


def test_offset_and_one_jump():
    truth = _line()
    p = truth.p_world_imu_m + np.array([5.0, -3.0, 2.0])  # a constant offset is no drift
    p[150:, 1] += 0.5                                     # one jump of 0.5 m sideways at frame 150
    d = drift_metrics(p[None], truth.R_world_imu[None], truth)
    np.testing.assert_allclose(d["max_jump_m"], [0.5])
    # segments spanning frame 150 are 0.5 m off: L = 100 starts 50..140 (10 of 20), L = 200 starts 0..140 with
    # last = start + 201 > 150 for every start in 0..90 (10 of 10)
    expected = (10 * 0.5 / 100 + 10 * 0.5 / 200) / 30
    np.testing.assert_allclose(d["drift_m_per_m"], [expected])


def test_short_drive_uses_10m_segments_and_no_kitti_figure():
    truth = _line(N=64)  # 63 m: segments of 10..60 m
    d = drift_metrics(1.02 * truth.p_world_imu_m[None], truth.R_world_imu[None], truth)
    assert np.isnan(d["t_rel_pct"][0]) and np.isnan(d["r_rel_deg_per_100m"][0])
    # starts 0, 10, ..., 60; length L ends at start + L + 1 <= 63
    segs = [(s, L) for L in range(10, 61, 10) for s in range(0, 64, 10) if s + L + 1 <= 63]
    np.testing.assert_allclose(d["drift_m_per_m"], [np.mean([0.02 * (L + 1) / L for _, L in segs])])


def test_drift_is_batched_and_non_finite_filters_get_nan():
    truth = _line()
    rng = np.random.default_rng(3)
    N = len(truth.p_world_imu_m)
    p = truth.p_world_imu_m[None] + np.cumsum(rng.normal(0, 0.05, (3, N, 3)), axis=1)
    R = so3_exp(np.cumsum(rng.normal(0, 0.001, (3, N, 3)), axis=1))
    p[2, 40] = np.nan
    batch = drift_metrics(p, R, truth)
    for k in range(2):
        single = drift_metrics(p[k:k + 1], R[k:k + 1], truth)
        for key, value in batch.items():
            np.testing.assert_allclose(value[k], single[key][0], rtol=1e-12)
    assert all(np.isnan(v[2]) for v in batch.values())
    with pytest.raises(MetricsError, match="do not match truth"):
        drift_metrics(p[:, :10], R[:, :10], truth)


@pytest.mark.parametrize("angle_rad", [1e-9, 1e-4, 0.3, 2.0, 3.1])
def test_geodesic_angle_is_the_norm_of_the_rotation_log(angle_rad):
    from avio.geometry import geodesic_angle_deg, so3_log

    rng = np.random.default_rng(3)
    A = so3_exp(rng.normal(size=(200, 3)))
    axis = rng.normal(size=(200, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    B = A @ so3_exp(axis * angle_rad)
    got = geodesic_angle_deg(A, B)
    log = np.degrees(np.linalg.norm(so3_log(np.swapaxes(A, -1, -2) @ B), axis=-1))
    assert np.allclose(got, np.degrees(angle_rad), rtol=1e-9, atol=1e-12)
    assert np.max(np.abs(got - log) / log) < 1e-12  # the same as scipy's log, to rounding
