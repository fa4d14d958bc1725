import numpy as np
import pytest

from avio.filter import FilterResult
from avio.geometry import so3_exp
from avio.metrics import MetricsError, pose_errors, position_rmse_objective
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
