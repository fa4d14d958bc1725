"""Where does each update's score excess enter: the update itself, its linearisation about an
uncertain relative pose, or the calibration's reach into the estimate the update starts from?
(issue 33: the route of the lag-0 excess of studies/objective/score_lags.py)

Each trifocal update scores its features' residuals at the *estimated* relative poses
``[psi12, dt12, psi13, dt13]`` of the triplet's cameras with ``S = J Sigma J^T + R`` (docs/model.md,
Eq. 37: ``Sigma = C P C^T`` the relative-pose covariance, J the residuals' Jacobian at the
estimate), a Gaussian to first order in the pose error; and under another calibration the filter
starts each update from another estimate. On fresh drives at the true calibration, from the
kernel's record of every update (``FilterResult.pose_cov``, ``update_poses``; ``record_used``):

1. **Consistency of Sigma**: the relative-pose error at each update,
   ``e = [Log(R1j_est^T R1j_true), t1j_true - t1j_est]`` (cameras from the IMU poses the update
   linearised about and the true extrinsic), its NEES ``e^T Sigma^-1 e / 12``, per axis, and the
   standard deviations the filter claims.
2. **One update's equality under drawn poses** (``--part draws``), on the drives' triplets with
   noise-free pixels (the drive simulated again without pixel noise), the features the filter used
   at the truth and the filter's own Sigma of that update: ``draws`` times, pixel noise of the
   filter's sigma and a relative-pose error drawn about Sigma; the triplet's joint NLL
   ``(r^T S^-1 r + log det S)/2`` (Woodbury over the 12 pose errors) at the intrinsics
   theta = (f = fx = fy, cx, cy) +- 1.5 px; ``sum_k Var(g_k) / sum_k E(h_k)`` per variable (1 for
   a correct density). Rows: exact poses and S = R (the feature model alone, on the drives' own
   geometry); errors from Sigma (a consistent filter's first-order update); errors of the measured
   size (Sigma scaled on each axis by its NEES).
3. **Total against partial scores** (``--part scores``): per update of 100 fresh drives, the score
   and curvature of the kernel's own update NLL in (f, cx, cy) taken two ways: *total*, the filter
   re-run at each calibration (as the objective does: the calibration also moves the estimate the
   update starts from); *partial*, the update re-scored at each calibration about the truth run's
   own recorded linearisation (poses, Sigma, features held; it reproduces the kernel's NLL at the
   truth to ~1e-9 nats, printed). The lag-0 ratio of each over the typical drives, and the total's
   split into the update's own score, the reach through the estimate (total - partial) and their
   covariance, each over the total's mean curvature.

    python studies/objective/pose_linearisation.py [--part draws|scores|both] [--sigmas 0.35 0.5 0.7 1.0] [--sim JSON] [--filter JSON]

Results: studies/objective/README.md, "Issue 33: the route of each update's excess". About 3 min
of CPU per pixel noise for the draws (4 drives), 2.5 min for the scores (100 drives).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numba
import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from feature_information import NAMES, STEP, USED, intrinsics_design
from information_equality import typical
from objective_bias import DRIVE, FRESH_SEED0
from score_lags import sim_config

from avio.filter.batch import run
from avio.filter.outliers import forward_lanes
from avio.filter.prepare import prepare
from avio.filter.trifocal import feature_residuals
from avio.filter.update import _noise_model
from avio.sim.simulator import simulate
from bench.problems.synthetic import Synthetic

M, D12 = len(USED), 12


def relative_poses(R_world_imu: np.ndarray, p_world_imu: np.ndarray, R_cam_imu: np.ndarray,
                   p_imu_cam_m: np.ndarray) -> tuple[np.ndarray, ...]:
    """Camera 2 and 3 in camera 1 (Eq. 21) from the IMU poses of the triplet's three frames:
    R_world_imu (..., 3, 3, 3), p_world_imu (..., 3, 3) with the frame on axis -3 / -2; returns
    R12, t12, R13, t13 ((..., 3, 3) and (..., 3); t in m)."""
    R_wc = R_world_imu @ R_cam_imu.T
    p_wc = p_world_imu + np.einsum("...ij,j->...i", R_world_imu, p_imu_cam_m)
    R1 = R_wc[..., 0, :, :]
    out = []
    for j in (1, 2):
        out.append(np.swapaxes(R1, -1, -2) @ R_wc[..., j, :, :])
        out.append(np.einsum("...ji,...j->...i", R1, p_wc[..., j, :] - p_wc[..., 0, :]))
    return tuple(out)


def pose_error(est: tuple, true: tuple) -> np.ndarray:
    """(..., 12) ``[psi12, dt12, psi13, dt13]`` with ``R1j_true = R1j_est Exp(psi1j)`` and
    ``t1j_true = t1j_est + dt1j`` (the measurement's perturbations, avio/filter/measurement.py)."""
    R12, t12, R13, t13 = est
    T12, u12, T13, u13 = true
    def log(A, B):
        rel = np.swapaxes(A, -1, -2) @ B
        return Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(rel.shape[:-1])
    return np.concatenate([log(R12, T12), u12 - t12, log(R13, T13), u13 - t13], axis=-1)


def prediction_error(est: tuple, true: tuple, Sigma: np.ndarray) -> np.ndarray:
    """(..., 6) squared errors over variances of the relative pose 2-3, ``[psi23, dt23]`` (camera 3
    in camera 2; clone k-1 to the predicted frame k: one frame of prediction), from the estimated
    and true (R12, t12, R13, t13) and Sigma (..., 12, 12) mapped by ``psi23 = psi13 - R23^T psi12``,
    ``dt23 = [t23]x psi12 + R12^T (dt13 - dt12)`` (avio/filter/measurement.py)."""
    def pair(R12, t12, R13, t13):
        return np.swapaxes(R12, -1, -2) @ R13, np.einsum("...ji,...j->...i", R12, t13 - t12)
    (A, a), (B, b) = pair(*est), pair(*true)
    rel = np.swapaxes(A, -1, -2) @ B
    e = np.concatenate([Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec().reshape(rel.shape[:-1]), b - a], -1)
    R12t = np.swapaxes(est[0], -1, -2)
    L = np.zeros(A.shape[:-2] + (6, 12))
    L[..., 0:3, 0:3], L[..., 0:3, 6:9] = -np.swapaxes(A, -1, -2), np.eye(3)
    L[..., 3:6, 3:6], L[..., 3:6, 9:12] = -R12t, R12t
    L[..., 3, 1], L[..., 3, 2], L[..., 4, 0] = -a[..., 2], a[..., 1], a[..., 2]
    L[..., 4, 2], L[..., 5, 0], L[..., 5, 1] = -a[..., 0], -a[..., 1], a[..., 0]
    return e**2 / np.diagonal(L @ Sigma @ np.swapaxes(L, -1, -2), axis1=-2, axis2=-1)


def perturbed(R12, t12, R13, t13, delta: np.ndarray) -> tuple[np.ndarray, ...]:
    """The six relative poses (R12, t12, R13, t13, R23, t23; Eq. 21) of ``D`` estimates whose errors
    are delta (D, 12) (pose_error's convention) about the true (R12, t12, R13, t13)."""
    A = R12 @ Rotation.from_rotvec(-delta[:, 0:3]).as_matrix()
    B = R13 @ Rotation.from_rotvec(-delta[:, 6:9]).as_matrix()
    a, b = t12 - delta[:, 3:6], t13 - delta[:, 9:12]
    return A, a, B, b, np.einsum("nji,njk->nik", A, B), np.einsum("nji,nj->ni", A, b - a)


# not cached: numba's cache of a script loaded by path (the tests) breaks the script run as __main__
@numba.njit
def _whitened(uv, R12, t12, R13, t13, R23, t23, intrinsics, sigma, used, Y, JW, LD, uv_noise=None):
    """For draw d (its pixels uv (D, F, 3, 2) and poses), intrinsics row p (fx, fy, cx, cy) and
    feature f: the whitened used residuals Y (D, P, F, M) = L^-1 r and Jacobian JW (D, P, F, M, 12)
    = L^-1 J with R_f = L L^T the filter's own noise model (update._noise_model, Eq. 35) taken at
    the pixels uv (as the filter does) or at uv_noise (D, F, 3, 2), and log det R_f into LD (D, P, F)."""
    D, F = uv.shape[0], uv.shape[1]
    m = len(used)
    r, J, G, r4, J4 = np.empty(4), np.empty((4, 12)), np.empty((4, 6)), np.empty(4), np.empty((4, 12))
    ru, Ju, Gp = np.empty((m, F)), np.empty((m, 12, F)), np.empty((m, 6, F))
    Rm, sd, Lm, ldR = np.empty((m, m, F)), np.empty((m, F)), np.zeros((m, m, F)), np.empty(F)
    y, col = np.empty((m, F)), np.empty((m, F))
    for d in range(D):
        T12 = (t12[d, 0], t12[d, 1], t12[d, 2])
        T13 = (t13[d, 0], t13[d, 1], t13[d, 2])
        T23 = (t23[d, 0], t23[d, 1], t23[d, 2])
        for p in range(intrinsics.shape[0]):
            fx, fy, cx, cy = intrinsics[p, 0], intrinsics[p, 1], intrinsics[p, 2], intrinsics[p, 3]
            for f in range(F):
                feature_residuals(uv[d, f], R12[d], T12, R13[d], T13, R23[d], T23, fx, fy, cx, cy, r, J, G, False)
                for a in range(m):
                    ru[a, f] = r[used[a]]
                    for c in range(12):
                        Ju[a, c, f] = J[used[a], c]
                if uv_noise is not None:  # the noise model's sensitivities at other pixels (r, J kept)
                    feature_residuals(uv_noise[d, f], R12[d], T12, R13[d], T13, R23[d], T23, fx, fy, cx, cy, r4, J4,
                                      G, False)
                for a in range(m):
                    for c in range(6):
                        Gp[a, c, f] = G[used[a], c]
            _noise_model(Gp, sigma, Rm, sd, Lm, ldR)
            forward_lanes(Lm, ru, y)
            for f in range(F):
                LD[d, p, f] = ldR[f]
                for a in range(m):
                    Y[d, p, f, a] = y[a, f]
            for c in range(12):
                for a in range(m):
                    for f in range(F):
                        col[a, f] = Ju[a, c, f]
                forward_lanes(Lm, col, y)
                for a in range(m):
                    for f in range(F):
                        JW[d, p, f, a, c] = y[a, f]


def joint_nll(Y: np.ndarray, JW: np.ndarray, LD: np.ndarray, Sigma: np.ndarray | None) -> np.ndarray:
    """(D, P) the triplet's joint NLL without its constant, ``(r^T S^-1 r + log det S)/2`` with
    ``S = R + J Sigma J^T`` (R block-diagonal over features; Sigma None: S = R) by Woodbury and the
    determinant lemma over the 12 pose errors, from _whitened's arrays."""
    q = (Y**2).sum(axis=(2, 3))
    ld = LD.sum(axis=2)
    if Sigma is not None:
        beta = np.einsum("dpfac,dpfa->dpc", JW, Y)
        A = np.linalg.inv(Sigma) + np.einsum("dpfac,dpfae->dpce", JW, JW)
        q = q - (beta * np.linalg.solve(A, beta[..., None])[..., 0]).sum(-1)
        ld = ld + np.linalg.slogdet(Sigma)[1] + np.linalg.slogdet(A)[1]
    return 0.5 * (q + ld)


def differences(nll: np.ndarray, step: np.ndarray = STEP) -> tuple[np.ndarray, np.ndarray]:
    """Score and curvature (..., 3) per variable (f, cx, cy) by central differences from the
    (..., 7) NLL at intrinsics_design's rows."""
    plus, minus = nll[..., 1::2], nll[..., 2::2]
    return (plus - minus) / (2 * step), (plus + minus - 2 * nll[..., :1]) / step**2


def score_moments(nll: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per variable (f, cx, cy) from the (D, 7) NLL at intrinsics_design's rows: the score's
    variance and mean over draws, and the mean curvature."""
    g, h = differences(nll)
    return g.var(axis=0, ddof=1), g.mean(axis=0), h.mean(axis=0)


def update_equality(uv_true: np.ndarray, poses_true: tuple, Sigma: np.ndarray, cal: tuple, sigma: float,
                    draws: int, rng, kappa: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """score_moments of one update: features uv_true (F, 3, 2) px, the true (R12, t12, R13, t13),
    the filter's Sigma (12, 12), the true (fx, fy, cx, cy); pixel noise of sigma px in every draw
    and, unless kappa is None, a relative-pose error from N(0, K Sigma K), K = diag(sqrt(kappa))
    (kappa (12,): each axis's variance over Sigma's), scored with S = R + J Sigma J^T (kappa None:
    exact poses, S = R)."""
    F = len(uv_true)
    noisy = uv_true[None] + sigma * rng.standard_normal((draws, F, 3, 2))
    delta = np.zeros((draws, D12))
    if kappa is not None:
        k = np.sqrt(kappa)
        delta = rng.multivariate_normal(np.zeros(D12), k[:, None] * Sigma * k[None, :], size=draws)
    poses = perturbed(*poses_true, delta)
    P = 7
    Y, JW, LD = np.empty((draws, P, F, M)), np.empty((draws, P, F, M, D12)), np.empty((draws, P, F))
    _whitened(noisy, *poses, intrinsics_design(cal), sigma, USED, Y, JW, LD)
    return score_moments(joint_nll(Y, JW, LD, None if kappa is None else Sigma))


def _problem(seed: int, sigma: float, filter_options: dict | None) -> Synthetic:
    """The flat-city problem of camera ``seed`` (its truth and filter settings: imposed decisions,
    the pixel noise sigma, FilterConfig overrides) whose filter runs the fresh drives."""
    return Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local",
                     filter={"outlier_decisions": "reference_all", "pixel_sigma_px": sigma, **(filter_options or {})})


def drive_updates(seed: int, index: int, sigma: float, sim: dict, filter_options: dict | None = None):
    """One fresh drive at pixel noise sigma and its noise-free twin, each filtered at the truth with
    the record on: (true calibration, true IMU poses (N, 3, 3) and (N, 3), the noisy run, the
    twin's prepared triplets and run)."""
    problem = _problem(seed, sigma, filter_options)
    camera = problem.sequence.truth_calibration
    truth = problem.calibration_space.decode(problem.truth[None])
    runs = []
    for s in (sigma, 0.0):
        drive = simulate(sim_config({**sim, "pixel_noise_px": s}), (seed, FRESH_SEED0 + index), true_calibration=camera)
        prep = prepare(drive, problem.filter_config)
        runs.append((drive, prep, run(drive, truth, problem.filter_config, prepared=prep, record_used=True)))
    return camera, runs


def sampled_updates(frames: np.ndarray, camera, clean, prep, res0):
    """For each update frame k in ``frames`` whose triplet the truth run res0 (on the noise-free twin
    ``clean``, its prepared triplets prep) updated with at least 3 features: (k, the features'
    noise-free pixels (F, 3, 2), the true (R12, t12, R13, t13) of the triplet)."""
    Rci, pic = camera.R_cam_imu[0], camera.p_imu_cam_m[0]
    for k in frames:
        j = prep.triplet_of_frame[k]
        feats = prep.valid[j] & res0.used[0, j]
        if j < 0 or feats.sum() < 3:
            continue
        t = k + np.array([-2, -1, 0])
        yield k, prep.uv_px[j][feats], relative_poses(clean.truth.R_world_imu[t], clean.truth.p_world_imu_m[t], Rci, pic)


def measure(seeds, n_drives: int, sigma: float, sim: dict, every: int, draws: int, seed: int = 0,
            filter_options: dict | None = None) -> dict:
    """NEES of the filter's relative-pose covariance at its updates and the pooled information
    ratios of one update without and with the pose uncertainty (module docstring)."""
    rng = np.random.default_rng(seed)
    nees, claimed, axes, predicted, updates = [], [], [], [], []
    for s in seeds:
        for i in range(n_drives):
            camera, ((drive, _, res), (clean, prep, res0)) = drive_updates(s, i, sigma, sim, filter_options)
            Rci, pic = camera.R_cam_imu[0], camera.p_imu_cam_m[0]
            frames = np.nonzero(res.dof[0] > 0)[0]
            poses = res.update_poses[0, frames]  # (K, 3, 4, 3)
            est = relative_poses(poses[:, :, :3, :], poses[:, :, 3, :], Rci, pic)
            idx = frames[:, None] + np.array([-2, -1, 0])
            true = relative_poses(drive.truth.R_world_imu[idx], drive.truth.p_world_imu_m[idx], Rci, pic)
            e = pose_error(est, true)
            Sig = res.pose_cov[0, frames]
            nees.append(np.einsum("ki,ki->k", e, np.linalg.solve(Sig, e[..., None])[..., 0]) / D12)
            claimed.append(np.sqrt(np.diagonal(Sig, axis1=1, axis2=2)))
            axes.append(e**2 / np.diagonal(Sig, axis1=1, axis2=2))
            predicted.append(prediction_error(est, true, Sig))
            cal = (camera.fx_px[0], camera.fy_px[0], camera.cx_px[0], camera.cy_px[0])
            for k in frames[::every]:
                j = prep.triplet_of_frame[k]
                feats = prep.valid[j] & res0.used[0, j] if j >= 0 else None
                if feats is None or feats.sum() < 3 or res0.dof[0, k] == 0:
                    continue
                t_idx = k + np.array([-2, -1, 0])
                pt = relative_poses(clean.truth.R_world_imu[t_idx], clean.truth.p_world_imu_m[t_idx], Rci, pic)
                updates.append((prep.uv_px[j][feats], pt, res.pose_cov[0, k], cal))
    out = {"nees": np.concatenate(nees), "claimed_sd": np.concatenate(claimed), "updates": len(updates),
           "nees_axes": np.concatenate(axes).mean(axis=0), "nees23_axes": np.concatenate(predicted).mean(axis=0)}
    # the rows: exact poses and S = R; poses from Sigma (a consistent filter); poses with the filter's
    # measured error per axis (Sigma scaled by each axis's NEES), each scored with S = R + J Sigma J^T
    for key, kappa in (("exact", None), ("consistent", np.ones(D12)), ("measured", out["nees_axes"])):
        var, mean, curv = (np.array(x) for x in zip(*[update_equality(*u, sigma, draws, rng, kappa) for u in updates]))
        out[key + "_ratio"] = var.sum(axis=0) / curv.sum(axis=0)
        # the mean score over updates and draws against its standard error (draws independent)
        out[key + "_t"] = mean.sum(axis=0) / np.sqrt(var.sum(axis=0) / draws)
    return out


def drive_scores(seed: int, index: int, sigma: float, sim: dict, filter_options: dict | None = None,
                 step: np.ndarray = STEP) -> dict:
    """Per update frame of one fresh drive at the truth, the score g (K, 3) and curvature h (K, 3)
    of the update's joint NLL in (f, cx, cy), taken two ways: *total*, the filter run at each
    intrinsics row (the calibration also moves the estimate the update starts from, as in the
    objective); *partial*, the update re-scored at each row about the truth run's own linearisation
    (its recorded poses, Sigma and features held). Also the two reconstructions' largest
    difference at the truth (the partial one re-computes the kernel's update NLL)."""
    problem = _problem(seed, sigma, filter_options)
    camera = problem.sequence.truth_calibration
    drive = simulate(sim_config({**sim, "pixel_noise_px": sigma}), (seed, FRESH_SEED0 + index), true_calibration=camera)
    cfg = problem.filter_config
    prep = prepare(drive, cfg)
    rows = intrinsics_design((camera.fx_px[0], camera.fy_px[0], camera.cx_px[0], camera.cy_px[0]), step)
    batch = camera.repeat(len(rows))
    batch = type(camera)(**{**batch.__dict__, "fx_px": rows[:, 0], "fy_px": rows[:, 1], "cx_px": rows[:, 2],
                            "cy_px": rows[:, 3]})
    res = run(drive, batch, cfg, prepared=prep, record_used=True)
    if res.diverged.any():
        return {}
    frames = np.nonzero(res.dof[0] > 0)[0]
    total = 0.5 * (res.nis + res.log_det_S)[:, frames].T  # (K, 7)
    Rci, pic = camera.R_cam_imu[0], camera.p_imu_cam_m[0]
    poses = res.update_poses[0, frames]
    R12, t12, R13, t13 = relative_poses(poses[:, :, :3, :], poses[:, :, 3, :], Rci, pic)
    R23 = np.einsum("kji,kjl->kil", R12, R13)
    t23 = np.einsum("kji,kj->ki", R12, t13 - t12)
    partial = np.empty_like(total)
    for n, k in enumerate(frames):
        j = prep.triplet_of_frame[k]
        uv = prep.uv_px[j][res.used[0, j]]
        F = len(uv)
        Y, JW, LD = np.empty((1, 7, F, M)), np.empty((1, 7, F, M, D12)), np.empty((1, 7, F))
        _whitened(uv[None], R12[n:n + 1], t12[n:n + 1], R13[n:n + 1], t13[n:n + 1], R23[n:n + 1], t23[n:n + 1],
                  rows, sigma, USED, Y, JW, LD)
        partial[n] = joint_nll(Y, JW, LD, res.pose_cov[0, k])[0]
    out = {"frames": frames, "check": float(np.max(np.abs(partial[:, 0] - total[:, 0])))}
    for key, nll in (("total", total), ("partial", partial)):
        out[key + "_g"], out[key + "_h"] = differences(nll, step)
    return out


def lag0_ratios(drives: list[dict], N: int) -> dict:
    """Per way (total, partial): ``sum_k Var(g_k) / sum_k E(h_k)`` per variable over the typical
    drives at fixed frames k (studies/objective/score_lags.py's lag 0; typical: the total NLL's
    curvature of the drive within 5 scaled MADs, information_equality.typical, the same drives for
    both ways), the same with the scores uncentred, and the mean drive score's t."""
    curv = np.array([r["total_h"].sum(axis=0) for r in drives])
    keep = typical(np.einsum("di,ij->dij", curv, np.eye(3)))
    drives = [r for r, k in zip(drives, keep) if k]
    out = {"typical": len(drives)}
    for key in ("total", "partial"):
        g, h = np.zeros((len(drives), N, 3)), np.zeros((len(drives), N, 3))
        for d, r in enumerate(drives):
            g[d, r["frames"]], h[d, r["frames"]] = r[key + "_g"], r[key + "_h"]
        curvature = h.mean(axis=0).sum(axis=0)
        out[key] = g.var(axis=0, ddof=1).sum(axis=0) / curvature
        out[key + "_uncentred"] = (g**2).mean(axis=0).sum(axis=0) / curvature
        s = g.sum(axis=1)
        out[key + "_t"] = s.mean(axis=0) / (s.std(axis=0, ddof=1) / np.sqrt(len(drives)))
        out[key + "_gh"] = g, h
    # total = partial + the reach through the estimate (indirect): where the excess sits, per variable
    # over the total curvature: Var(partial), Var(indirect), 2 Cov(partial, indirect); E h of each part
    (gp, hp), (gt, ht) = out.pop("partial_gh"), out.pop("total_gh")
    gi, hi = gt - gp, ht - hp
    H = ht.mean(axis=0).sum(axis=0)
    def cov(a, b):
        return ((a - a.mean(axis=0)) * (b - b.mean(axis=0))).sum(axis=0).sum(axis=0) / (len(drives) - 1)
    out["split"] = np.array([cov(gp, gp), cov(gi, gi), 2 * cov(gp, gi), hp.mean(axis=0).sum(axis=0),
                             hi.mean(axis=0).sum(axis=0)]) / H
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="cameras (data seeds) of the draws")
    parser.add_argument("--drives", type=int, default=2, help="fresh drives per camera of the draws")
    parser.add_argument("--score-seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras of the scores")
    parser.add_argument("--score-drives", type=int, default=20, help="fresh drives per camera of the scores")
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.35, 0.5, 0.7, 1.0], help="pixel noise, px")
    parser.add_argument("--every", type=int, default=5, help="every n-th update frame in the draws")
    parser.add_argument("--draws", type=int, default=100, help="noise draws per update")
    parser.add_argument("--sim", default=None, help="SimConfig overrides as JSON (default: exact IMU, no outliers)")
    parser.add_argument("--filter", type=json.loads, default=None, help="FilterConfig overrides as JSON")
    parser.add_argument("--step-scale", type=float, default=1.0, help="the scores' difference steps x this (1: 1.5 px)")
    parser.add_argument("--part", choices=["draws", "scores", "both"], default="both")
    args = parser.parse_args(argv)
    sim = json.loads(args.sim) if args.sim else {"imu_noise_on": False, "outlier_fraction": 0}
    def row(v, fmt="{:.3f}"):
        return ", ".join(fmt.format(x) for x in v)
    if args.part in ("draws", "both"):
        print(f"{DRIVE}, sim {sim}, filter {args.filter or 'default'} at the data's pixel noise; cameras {args.seeds} x {args.drives} drives; "
              f"{args.draws} draws per update, every {args.every}th update")
        print("| σ (px) | updates | relative-pose NEES/12 (mean, median) | filter's σ: rotation (°); translation "
              "lateral, forward (mm) | Var(g)/E(h) (" + ", ".join(NAMES) + "): exact poses, S = R | poses from Σ | "
              "poses with the measured errors (Σ scaled per axis by its NEES) | t: exact | t: from Σ |")
        print("|---|---|---|---|---|---|---|---|---|")
        per_axis = []
        for sigma in args.sigmas:
            m = measure(args.seeds, args.drives, sigma, sim, args.every, args.draws, filter_options=args.filter)
            sd = np.median(m["claimed_sd"], axis=0)
            rot = np.degrees(np.sqrt((sd[0:3] ** 2).mean()))
            lateral = 1e3 * np.sqrt((sd[3:5] ** 2).mean())
            print(f"| {sigma:g} | {m['updates']} | {m['nees'].mean():.2f}, {np.median(m['nees']):.2f} | {rot:.4f}; "
                  f"{lateral:.1f}, {1e3 * sd[5]:.1f} | {row(m['exact_ratio'])} | {row(m['consistent_ratio'])} | "
                  f"{row(m['measured_ratio'])} | {row(m['exact_t'], '{:+.1f}')} | {row(m['consistent_t'], '{:+.1f}')} |",
                  flush=True)
            per_axis.append(f"| {sigma:g} | " + " | ".join(row(m["nees_axes"][a:a + 3], "{:.2f}") for a in range(0, 12, 3))
                            + " | " + " | ".join(row(m["nees23_axes"][a:a + 3], "{:.2f}") for a in (0, 3)) + " |")
        print("\nper axis (e_i^2 / Sigma_ii, camera 1's x right, y down, z forward; 2-3: clone k-1 to the predicted "
              "frame k):\n\n| σ (px) | ψ12 | dt12 | ψ13 | dt13 | ψ23 | dt23 |\n|---|---|---|---|---|---|---|\n"
              + "\n".join(per_axis))
    if args.part in ("scores", "both"):
        print(f"\n{DRIVE}, sim {sim}, filter {args.filter or 'default'}; cameras {args.score_seeds} x {args.score_drives} fresh drives: each update's "
              "score at the truth, total (the filter re-run at each calibration) and partial (about the truth run's "
              f"own linearisation); steps {args.step_scale * STEP} px")
        print("| σ (px) | typical drives | lag 0, total (" + ", ".join(NAMES) + ") | lag 0, partial | t, total | t, partial | "
              "largest |partial - kernel| at the truth |")
        print("|---|---|---|---|---|---|---|")
        splits = []
        for sigma in args.sigmas:
            drives = [r for s in args.score_seeds for i in range(args.score_drives)
                      if (r := drive_scores(s, i, sigma, sim, args.filter, args.step_scale * STEP))]
            N = 1 + max(int(r["frames"].max()) for r in drives)
            m = lag0_ratios(drives, N)
            check = max(r["check"] for r in drives)
            print(f"| {sigma:g} | {m['typical']} of {len(drives)} | {row(m['total'])} | {row(m['partial'])} | {row(m['total_t'], '{:+.1f}')}"
                  f" | {row(m['partial_t'], '{:+.1f}')} | {check:.1e} |", flush=True)
            splits.append(f"| {sigma:g} | " + " | ".join(row(v, "{:+.2f}" if i == 2 else "{:.2f}") for i, v in enumerate(m["split"]))
                          + " |")
        print("\nthe total's lag 0 split, per variable (" + ", ".join(NAMES) + ") over the total's mean curvature: the "
              "update's own score (partial), the reach through the estimate (indirect = total - partial), twice their "
              "covariance; and the two parts' mean curvatures\n\n| σ (px) | Var(partial) | Var(indirect) | 2 Cov | "
              "E h, partial | E h, indirect |\n|---|---|---|---|---|---|\n" + "\n".join(splits))


if __name__ == "__main__":
    main()
