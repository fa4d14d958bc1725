"""Is the trifocal update's score unbiased at the true relative pose? Its mean over pixel noise, in the
update's own information, and its coherence across updates (issue 33: the clones' lateral error
beyond P).

Each update scores its features with ``beta = sum_f J_f^T R_f^-1 r_f`` (docs/model.md, Eq. 40), the
Jacobian J_f of the residuals w.r.t. the relative pose taken at the *measured* pixels. J_f then
carries the pixel noise that r_f carries, so at the true pose ``E[beta] = sigma^2 sum_j
(dJ/du_j)^T R^-1 (dr/du_j)`` (an errors-in-variables bias, second order in the pixel noise) rather
than 0. On the drives' own triplets (pose_linearisation.py's noise-free twins, the features the
filter used at the truth), every ``every``-th update, ``draws`` pixel-noise draws at the true pose:

- ``z = E[beta]^T A^+ E[beta]`` per update (A the mean information ``J^T R^-1 J``; the draws'
  sampling, ``tr(A^+ Cov(beta))/draws``, subtracted), also per eigen-direction of A: a bias of z
  per update that points the same way over N updates moves the estimate by ~N z of its claimed
  variance, which one update's consistency (update_consistency.py) cannot see;
- the cosine of consecutive sampled updates' biases (whitened by A^+): their coherence;
- with ``--jacobian true`` the Jacobian (and the noise model) at the true pixels, so only r
  carries the noise: the control, z ~ 0.

    python studies/objective/score_bias.py [--sigma 1.0] [--draws 1000] [--every 10] [--jacobian measured|true]

About 4 min of CPU at the defaults (two fresh drives, 142 updates).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from feature_information import USED
from pose_linearisation import D12, M, _whitened, drive_updates, perturbed, sampled_updates

SIM = {"imu_noise_on": False, "outlier_fraction": 0}


def update_bias(uv: np.ndarray, true: tuple, cal: np.ndarray, sigma: float, draws: int, rng,
                jacobian_at_true: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One update's features uv (F, 3, 2) px at the true (R12, t12, R13, t13): (the mean score (12,),
    its sampling covariance over the draws (12, 12) divided by draws, the mean information A (12, 12))."""
    F = len(uv)
    poses = perturbed(*true, np.zeros((draws, D12)))
    noisy = uv[None] + sigma * rng.standard_normal((draws, F, 3, 2))
    clean = np.ascontiguousarray(np.broadcast_to(uv[None], noisy.shape))
    Y, JW, LD = np.empty((draws, 1, F, M)), np.empty((draws, 1, F, M, D12)), np.empty((draws, 1, F))
    _whitened(noisy, *poses, cal, sigma, USED, Y, JW, LD, clean if jacobian_at_true else None)
    if jacobian_at_true:  # the Jacobian at the true pixels, whitened by the same noise model
        JW = np.empty_like(JW)
        _whitened(clean, *poses, cal, sigma, USED, np.empty_like(Y), JW, np.empty_like(LD), clean)
    beta = np.einsum("dfac,dfa->dc", JW[:, 0], Y[:, 0])
    A = np.einsum("dfac,dfae->ce", JW[:, 0], JW[:, 0]) / draws
    return beta.mean(axis=0), np.cov(beta.T) / draws, A


def measure(sigma: float, draws: int, every: int, jacobian_at_true: bool, seeds=(0, 1), seed: int = 0) -> dict:
    """z per update (and per eigen-direction of A, largest information first) and the cosines of
    consecutive sampled updates' biases, over every ``every``-th update of one fresh drive per camera."""
    rng = np.random.default_rng(seed)
    z, by_direction, cosines = [], [], []
    for s in seeds:
        camera, ((_, _, res), (clean, prep, res0)) = drive_updates(s, 0, sigma, SIM)
        cal = np.array([[camera.fx_px[0], camera.fy_px[0], camera.cx_px[0], camera.cy_px[0]]])
        previous = None
        for _, uv, true in sampled_updates(np.nonzero(res0.dof[0] > 0)[0][::every], camera, clean, prep, res0):
            b, V, A = update_bias(uv, true, cal, sigma, draws, rng, jacobian_at_true)
            Ap = np.linalg.pinv(A, rcond=1e-8, hermitian=True)
            z.append(b @ Ap @ b - np.trace(Ap @ V))
            lam, U = np.linalg.eigh(A)
            by_direction.append(((U.T @ b) ** 2 / np.where(lam > 1e-8 * lam.max(), lam, np.inf))[::-1])
            if previous is not None:
                a = previous
                cosines.append(a @ Ap @ b / np.sqrt((a @ Ap @ a) * (b @ Ap @ b)))
            previous = b
    return {"z": np.array(z), "by_direction": np.mean(by_direction, axis=0), "cosine": np.array(cosines)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sigma", type=float, default=1.0, help="pixel noise, px")
    parser.add_argument("--draws", type=int, default=1000, help="pixel-noise draws per update")
    parser.add_argument("--every", type=int, default=10, help="every n-th update frame")
    parser.add_argument("--jacobian", choices=("measured", "true"), default="measured",
                        help="pixels the Jacobian and the noise model are taken at")
    args = parser.parse_args(argv)
    m = measure(args.sigma, args.draws, args.every, args.jacobian == "true")
    z, c = m["z"], m["cosine"]
    print(f"exact IMU, {args.sigma:g} px, Jacobian at the {args.jacobian} pixels: {len(z)} updates x {args.draws} draws")
    print(f"z per update: mean {z.mean():.4f} ± {z.std() / np.sqrt(len(z)):.4f}, median {np.median(z):.4f}")
    print("z per eigen-direction of A (largest information first):", np.round(m["by_direction"], 4))
    print(f"cosine of consecutive sampled updates' biases: mean {c.mean():.3f} ± {c.std() / np.sqrt(len(c)):.3f}")


if __name__ == "__main__":
    main()
