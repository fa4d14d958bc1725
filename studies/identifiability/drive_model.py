"""The simulator's measurement model of a drive, at the truth (issue 33; docs/model.md, Eqs. 58-60):
the pixels of its inlier triplet features (:func:`drive_observations`: the tracks, or independent
triplets), their projection and its Jacobians, and the IMU between consecutive frames (Euler
preintegration, the interval's residual, its Jacobians and covariance). Used by data_bound.py, which
turns it into the calibration's Fisher information.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from avio.geometry import so3_exp, so3_log

#: central-difference steps of the calibration's local variables (px, deg, m): the model is smooth
CAL_STEP = np.array([1e-3] * 4 + [1e-4] * 3 + [1e-5] * 3)


def project(R_world_imu, p_world_imu, X_world, fx, fy, cx, cy, R_cam_imu, p_imu_cam) -> np.ndarray:
    """(n, 2) pixels of world points X_world (n, 3) seen from IMU poses (n, 3, 3), (n, 3) through a
    camera (fx..cy (n,) px, R_cam_imu (n, 3, 3), p_imu_cam (n, 3) m) (docs/model.md, Eqs. 5, 20)."""
    R_world_cam = R_world_imu @ np.swapaxes(R_cam_imu, -1, -2)
    p_world_cam = p_world_imu + np.einsum("nij,nj->ni", R_world_imu, p_imu_cam)
    x = np.einsum("nji,nj->ni", R_world_cam, X_world - p_world_cam)
    return np.stack([fx * x[:, 0] / x[:, 2] + cx, fy * x[:, 1] / x[:, 2] + cy], axis=1)


def _rotate(R: np.ndarray, axis: int, h: float) -> np.ndarray:
    """R exp(h e_axis): a body-frame (right) perturbation of rotations (n, 3, 3)."""
    e = np.zeros(3)
    e[axis] = h
    return R @ so3_exp(e)


def reprojection_jacobians(R, p, X, cal_truth, cal_plus, cal_minus) -> dict[str, np.ndarray]:
    """Each observation's pixel ``uv`` (n, 2) at the truth (cal_truth: a Calibration batch of 1) and the
    central-difference Jacobians of :func:`project` there: ``theta``, ``p``, ``X`` (n, 2, 3) and ``cal``
    (n, 2, 10) (cal_plus/cal_minus: the 10 calibrations one step up and down each local variable, as
    Calibration batches of 10)."""
    def cam(c, j):
        n = len(R)
        return (np.full(n, c.fx_px[j]), np.full(n, c.fy_px[j]), np.full(n, c.cx_px[j]), np.full(n, c.cy_px[j]),
                np.broadcast_to(c.R_cam_imu[j], (n, 3, 3)), np.broadcast_to(c.p_imu_cam_m[j], (n, 3)))

    truth = cam(cal_truth, 0)
    out = {"uv": project(R, p, X, *truth), **{k: np.zeros((len(R), 2, 3)) for k in ("theta", "p", "X")}}
    for a in range(3):
        hr, hp = 1e-6, 1e-5
        up, down = project(_rotate(R, a, hr), p, X, *truth), project(_rotate(R, a, -hr), p, X, *truth)
        out["theta"][:, :, a] = (up - down) / (2 * hr)
        e = np.zeros(3)
        e[a] = hp
        out["p"][:, :, a] = (project(R, p + e, X, *truth) - project(R, p - e, X, *truth)) / (2 * hp)
        out["X"][:, :, a] = (project(R, p, X + e, *truth) - project(R, p, X - e, *truth)) / (2 * hp)
    out["cal"] = np.stack([(project(R, p, X, *cam(cal_plus, j)) - project(R, p, X, *cam(cal_minus, j)))
                           / (2 * CAL_STEP[j]) for j in range(10)], axis=2)
    return out


def preintegrate(gyro: np.ndarray, accel: np.ndarray, bg: np.ndarray, ba: np.ndarray, dt: float):
    """Euler preintegration of each interval's samples (n, s, 3) with biases (n, 3) (Eq. 59):
    (dR (n, 3, 3), dv (n, 3), dp (n, 3)) in the interval's first IMU frame."""
    n, s, _ = gyro.shape
    dR = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    dv, dp = np.zeros((n, 3)), np.zeros((n, 3))
    for i in range(s):
        acc = np.einsum("nij,nj->ni", dR, accel[:, i] - ba)
        dp += dv * dt + 0.5 * acc * dt * dt
        dv += acc * dt
        dR = dR @ so3_exp((gyro[:, i] - bg) * dt)
    return dR, dv, dp


def imu_residual(truth, x0: np.ndarray, x1: np.ndarray, gyro, accel, dt: float, gravity: np.ndarray) -> np.ndarray:
    """(n, 9) residual of the IMU between consecutive frames (Eq. 60): states x0 (n, 15) and x1 (n, 9)
    as perturbations ``[theta, p, v, b_a, b_g]`` of the truth (R0, p0, v0, b_a0, b_g0, R1, p1, v1: each
    interval's first frame and its last, (n, ...)); gyro, accel (n, s, 3) the interval's samples."""
    R0, p0, v0, ba0, bg0, R1, p1, v1 = truth
    Ra = R0 @ so3_exp(x0[:, 0:3])
    Rb = R1 @ so3_exp(x1[:, 0:3])
    pa, va, pb, vb = p0 + x0[:, 3:6], v0 + x0[:, 6:9], p1 + x1[:, 3:6], v1 + x1[:, 6:9]
    dR, dv, dp = preintegrate(gyro, accel, bg0 + x0[:, 12:15], ba0 + x0[:, 9:12], dt)
    T = dt * gyro.shape[1]
    RaT = np.swapaxes(Ra, -1, -2)
    r_R = so3_log(np.swapaxes(dR, -1, -2) @ RaT @ Rb)
    r_v = np.einsum("nij,nj->ni", RaT, vb - va - gravity * T) - dv
    r_p = np.einsum("nij,nj->ni", RaT, pb - pa - va * T - 0.5 * gravity * T * T) - dp
    return np.concatenate([r_R, r_v, r_p], axis=1)


def imu_factors(truth, gyro, accel, dt: float, gravity: np.ndarray, accel_sigma: float, gyro_sigma: float):
    """The IMU residual of each interval (n intervals of s samples; per-sample noise sigmas) in the states
    ``[x_k (15), x_{k+1} (theta, p, v)]``: (whitened Jacobians (n, 9, 24) by central differences, Cholesky
    factors (n, 9, 9) of the residual's covariance, the samples' noise carried through the
    preintegration (Eq. 61))."""
    n = len(gyro)
    z0, z1 = np.zeros((n, 15)), np.zeros((n, 9))
    J = np.zeros((n, 9, 24))
    steps = np.r_[[1e-6] * 3, [1e-5] * 3, [1e-5] * 3, [1e-5] * 3, [1e-7] * 3]
    for j in range(24):
        h = steps[j] if j < 15 else steps[j - 15]
        a0, a1 = z0.copy(), z1.copy()
        b0, b1 = z0.copy(), z1.copy()
        (a0 if j < 15 else a1)[:, j if j < 15 else j - 15] = h
        (b0 if j < 15 else b1)[:, j if j < 15 else j - 15] = -h
        up = imu_residual(truth, a0, a1, gyro, accel, dt, gravity)
        down = imu_residual(truth, b0, b1, gyro, accel, dt, gravity)
        J[:, :, j] = (up - down) / (2 * h)
    # the residual's covariance: derivatives in each sample's noise, times its variance
    s = gyro.shape[1]
    cov = np.zeros((n, 9, 9))
    for which, sigma, h in ((gyro, gyro_sigma, 1e-7), (accel, accel_sigma, 1e-5)):
        for i in range(s):
            for a in range(3):
                up, down = which.copy(), which.copy()
                up[:, i, a] += h
                down[:, i, a] -= h
                args_up = (up, accel) if which is gyro else (gyro, up)
                args_down = (down, accel) if which is gyro else (gyro, down)
                d = (imu_residual(truth, z0, z1, *args_up, dt, gravity)
                     - imu_residual(truth, z0, z1, *args_down, dt, gravity)) / (2 * h)
                cov += sigma**2 * d[:, :, None] * d[:, None, :]
    L = np.linalg.cholesky(cov)
    return np.linalg.solve(L, J), L


class Pixels(NamedTuple):  # a NamedTuple: the tests load this script by path, outside sys.modules
    """Which pixels the bound counts. max_features: keep this many of every triplet's inlier features
    (at random; None: all). triplets: every triplet feature its own unknown point and its three pixels
    its own (the data of ``SimConfig.pixel_noise_per_triplet``: the triplets' measurements as the filter
    models them, independent, and no track linking them); default: the drive's distinct pixels, one
    unknown point per landmark."""

    max_features: int | None = None
    triplets: bool = False


def drive_observations(seq, world, pixels: Pixels = Pixels(), rng=None):
    """The drive's inlier pixels: (frame (m,), landmark (m,) row of ``world.landmarks_world``, point (m,):
    the unknown point each belongs to, uv (m, 2) the measured pixel), from the simulator's own tracks (the
    triplets re-drawn with the sequence's tracks stream, checked equal to the sequence's); rng draws
    ``pixels.max_features``."""
    from avio.sim.camera import simulate_tracks
    from avio.sim.simulator import SimConfig, _seed_streams  # the sequence's own random streams

    meta = seq.meta
    config = SimConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in meta["config"].items()
                          if k != "imu_noise"}, imu_noise=seq.imu_noise)
    streams = _seed_streams(tuple(np.atleast_1d(meta["seed"])), None if "noise_seed" not in meta
                            else tuple(np.atleast_1d(meta["noise_seed"])))
    tracks, details = simulate_tracks(
        world.trajectory, seq.frame_t_s, seq.truth_calibration, world.landmarks_world, config.image_size_px,
        config.pixel_noise_px, config.outlier_fraction, config.max_features, np.random.default_rng(streams["tracks"]),
        return_details=True, noise_per_triplet=config.pixel_noise_per_triplet)
    if not np.array_equal(tracks.uv_px, seq.tracks.uv_px):
        raise RuntimeError(f"{seq.name}: the re-drawn tracks differ from the sequence's")
    keep = tracks.valid & ~details["outlier"]
    if pixels.max_features is not None:
        score = np.where(keep, rng.random(keep.shape), np.inf)
        keep &= np.argsort(np.argsort(score, axis=1), axis=1) < pixels.max_features
    t, f = np.nonzero(keep)
    frames = np.concatenate([tracks.frame_index[t] - 2 + j for j in range(3)])
    landmarks = np.tile(details["landmark_id"][t, f], 3)
    uv = np.concatenate([tracks.uv_px[t, f, j] for j in range(3)])
    if pixels.triplets:
        return frames, landmarks, np.tile(np.arange(len(t)), 3), uv
    pairs, first = np.unique(np.stack([frames, landmarks], axis=1), axis=0, return_index=True)
    return pairs[:, 0], pairs[:, 1], np.unique(pairs[:, 1], return_inverse=True)[1], uv[first]
