"""Is one feature's Gaussian measurement model a likelihood for its own residuals? The
information-matrix equality of a single trifocal feature at the true poses (issue 33: where each
update's own excess comes from).

The filter scores a feature's used residuals r (the 1-2 Sampson distance and the transfer to
image 3; docs/model.md, Eq. 29) as Gaussian with the pixel covariance of Eq. 35,
``R_f = sigma^2 G_f G_f^T + (eps sigma)^2 I`` (G_f the residuals' pixel sensitivities at the
measured points, Eq. 34), ``l = (r^T R_f^-1 r + log det R_f) / 2``. Here the poses are exact (no
filter, no pose uncertainty): only the pixel noise is drawn, many times per feature, and the
score ``g = dl/dtheta`` and curvature ``h = d2l/dtheta2`` are taken by central differences in the
intrinsics theta = (f = fx = fy, cx, cy). For a correct density ``Var(g) = E(h)``; the ratio
``sum_f Var(g_f) / sum_f E(h_f)`` (the features of a triplet are independent) above 1 is the
excess a single update carries before any filter enters, and NIS/dof above 1 says R_f is too
small for the residuals.

The triplets: a KITTI-like camera (718.856 px, principal point (607.19, 185.22), 1241 x 376)
moving forward 0.69 m per frame (6.9 m/s at 10 Hz) while turning at a given yaw rate, points in
front of it at depths 5-60 m seen in all three images; features whose transfer moves more than
``max_transfer_gain`` px per px (FilterConfig's 50) are dropped as the filter drops them.

    python studies/objective/feature_information.py [--sigmas 0.2 0.35 0.5 0.7 1.0] [--yaw-rates 0 0.2 0.5] [--draws 400]

Seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numba
import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.filter.outliers import forward_lanes
from avio.filter.trifocal import feature_residuals
from avio.filter.update import USED_RESIDUALS, _noise_model

FX, CX, CY, SIZE = 718.856, 607.1928, 185.2157, (1241, 376)
STEP = np.array([1.5, 1.5, 1.5])  # px: f, cx, cy (information_equality.py's steps)
NAMES = ("f", "cx", "cy")
USED = np.array(USED_RESIDUALS)


def triplet(yaw_rate: float, n_points: int, rng, step_m: float = 0.69, dt: float = 0.1):
    """The relative poses (R12, t12, R13, t13, R23, t23; camera j in camera 1, Eq. 21) of a
    forward-moving camera turning at yaw_rate rad/s, and the true pixels (F, 3, 2) of points seen
    in all three images."""
    R = [Rotation.from_rotvec([0.0, -yaw_rate * dt * j, 0.0]).as_matrix() for j in (1, 2)]
    t = [np.array([0.0, 0.0, step_m * j]) for j in (1, 2)]
    K = np.array([[FX, 0, CX], [0, FX, CY], [0, 0, 1.0]])
    uv = np.column_stack([rng.uniform(20, SIZE[0] - 20, n_points), rng.uniform(20, SIZE[1] - 20, n_points)])
    depth = rng.uniform(5.0, 60.0, n_points)
    X = depth[:, None] * (np.linalg.inv(K) @ np.column_stack([uv, np.ones(n_points)]).T).T
    pix = [uv]
    keep = np.ones(n_points, bool)
    for Rj, tj in zip(R, t):
        Xj = (X - tj) @ Rj  # R1j^T (X - t1j), rows
        keep &= Xj[:, 2] > 1.0
        p = (K @ Xj.T).T
        pj = p[:, :2] / p[:, 2:3]
        keep &= (pj[:, 0] > 0) & (pj[:, 0] < SIZE[0]) & (pj[:, 1] > 0) & (pj[:, 1] < SIZE[1])
        pix.append(pj)
    uv3 = np.stack(pix, axis=1)[keep]
    R12, R13 = R
    t12, t13 = t
    R23, t23 = R12.T @ R13, R12.T @ (t13 - t12)
    poses = (R12, tuple(t12), R13, tuple(t13), R23, tuple(t23))
    return poses, uv3


# not cached: numba's cache of a script loaded by path (the tests) breaks the script run as __main__
@numba.njit
def _nll(uv, R12, t12, R13, t13, R23, t23, intrinsics, sigma, used, out, nis, gain):
    """Per draw d, feature f and intrinsics row p: the feature's NLL into out (D, F, P), scored as
    the filter scores it (its own R_f, Cholesky and log det: update._noise_model, Eq. 35); NIS at
    row 0 into nis (D, F); the largest transfer gain at row 0 into gain (D, F)."""
    F, m = uv.shape[1], len(used)
    r, J, G = np.empty(4), np.empty((4, 12)), np.empty((4, 6))
    ru, Gp = np.empty((m, F)), np.empty((m, 6, F))
    Rm, sd, Lm, ldR = np.empty((m, m, F)), np.empty((m, F)), np.zeros((m, m, F)), np.empty(F)
    y = np.empty((m, F))
    for d in range(uv.shape[0]):
        for p in range(intrinsics.shape[0]):
            fx, fy, cx, cy = intrinsics[p, 0], intrinsics[p, 1], intrinsics[p, 2], intrinsics[p, 3]
            for f in range(F):
                feature_residuals(uv[d, f], R12, t12, R13, t13, R23, t23, fx, fy, cx, cy, r, J, G, False)
                for a in range(m):
                    ru[a, f] = r[used[a]]
                    for c in range(6):
                        Gp[a, c, f] = G[used[a], c]
                if p == 0:
                    g = 0.0
                    for a in range(2, 4):
                        for c in range(4):
                            g = max(g, abs(G[a, c]))
                    gain[d, f] = g
            _noise_model(Gp, sigma, Rm, sd, Lm, ldR)
            forward_lanes(Lm, ru, y)
            for f in range(F):
                q = 0.0
                for a in range(m):
                    q += y[a, f] * y[a, f]
                out[d, f, p] = 0.5 * (q + ldR[f])
                if p == 0:
                    nis[d, f] = q


def intrinsics_design(base=(FX, FX, CX, CY), step: np.ndarray = STEP) -> np.ndarray:
    """(7, 4) rows (fx, fy, cx, cy): the truth ``base``, then each of f (fx and fy together), cx, cy
    at +-step (px)."""
    base = np.asarray(base, float)
    rows = [base]
    for i in range(3):
        for sign in (1.0, -1.0):
            row = base.copy()
            if i == 0:
                row[:2] += sign * step[0]
            else:
                row[1 + i] += sign * step[i]
            rows.append(row)
    return np.array(rows)


def measure(sigma: float, yaw_rate: float, draws: int, n_points: int = 300, max_gain: float = 50.0, seed: int = 0,
            data_sigma: float | None = None) -> dict:
    """Information ratio per intrinsic, NIS/dof and the mean score's t over draws of the pixel noise
    at the truth of one triplet; the model's noise is sigma, the data's data_sigma (default sigma)."""
    rng = np.random.default_rng(seed)
    poses, uv3 = triplet(yaw_rate, n_points, rng)
    noisy = uv3[None] + (sigma if data_sigma is None else data_sigma) * rng.standard_normal((draws,) + uv3.shape)
    out = np.empty((draws, len(uv3), 7))
    nis, gain = np.empty((draws, len(uv3))), np.empty((draws, len(uv3)))
    _nll(noisy, *poses, intrinsics_design(), sigma, USED, out, nis, gain)
    # the filter drops a feature whose transfer gain exceeds the limit: judged on the noise-free pixels
    clean = np.empty((1, len(uv3), 7))
    clean_nis, clean_gain = np.empty((1, len(uv3))), np.empty((1, len(uv3)))
    _nll(uv3[None], *poses, intrinsics_design(), sigma, USED, clean, clean_nis, clean_gain)
    keep = clean_gain[0] <= max_gain
    out, nis = out[:, keep], nis[:, keep]
    plus, minus = out[:, :, 1::2], out[:, :, 2::2]
    g = (plus - minus) / (2 * STEP)  # (D, F, 3)
    h = (plus + minus - 2 * out[:, :, :1]) / STEP**2
    curvature = h.mean(axis=0).sum(axis=0)
    # a variable one triplet does not determine (f under pure forward motion: scaling about the
    # epipole at the principal point moves no point off its epipolar line) has no ratio
    determined = curvature > 1e-6 * curvature.max()
    ratio = np.where(determined, g.var(axis=0, ddof=1).sum(axis=0) / np.where(determined, curvature, 1.0), np.nan)
    total = g.sum(axis=1)  # the triplet's score per draw
    t = total.mean(axis=0) / (total.std(axis=0, ddof=1) / np.sqrt(draws))
    return {"features": int(keep.sum()), "ratio": ratio, "nis_per_dof": float(nis.mean() / len(USED)), "t": t}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.2, 0.35, 0.5, 0.7, 1.0], help="pixel noise, px")
    parser.add_argument("--yaw-rates", type=float, nargs="+", default=[0.0, 0.2, 0.5], help="rad/s")
    parser.add_argument("--draws", type=int, default=400, help="noise draws per feature")
    args = parser.parse_args(argv)
    print("| yaw rate (rad/s) | σ (px) | features | Var(g)/E(h): " + ", ".join(NAMES) + " | NIS/dof | mean score t: "
          + ", ".join(NAMES) + " |")
    print("|---|---|---|---|---|---|")
    for yaw in args.yaw_rates:
        for sigma in args.sigmas:
            m = measure(sigma, yaw, args.draws)
            print(f"| {yaw:g} | {sigma:g} | {m['features']} | " + ", ".join(f"{v:.3f}" for v in m["ratio"])
                  + f" | {m['nis_per_dof']:.3f} | " + ", ".join(f"{v:+.1f}" for v in m["t"]) + " |")


if __name__ == "__main__":
    main()
