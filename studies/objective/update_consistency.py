"""Does one trifocal update leave a consistent posterior? The relative-pose NEES after a single
update from a consistent prior, on the drives' own triplets (issue 33: where the clones' lateral
error beyond P comes from, studies/objective/pose_linearisation.py).

At sampled update frames of fresh drives (as pose_linearisation.py's draws: noise-free pixels of
the features the filter used at the truth, the filter's own relative-pose covariance Sigma of that
update), ``draws`` times: a prior error ``e0 ~ N(0, Sigma)`` of the relative pose
``[psi12, dt12, psi13, dt13]``, pixel noise of the filter's sigma, and the update as the filter
makes it in the relative-pose space (docs/model.md, Eqs. 40-42 with C = I): residuals and Jacobians
at the prior estimate, ``delta = Sigma (I + A Sigma)^-1 beta``,
``Sigma+ = Sigma - Sigma (I + A Sigma)^-1 A Sigma``; the posterior error ``e1 = e0 - delta`` per
axis over ``Sigma+``'s diagonal (1 is consistent). The noise model R_f is taken at the measured
pixels (as the filter does) or at the true ones (its weights then independent of the noise they
weight).

    python studies/objective/update_consistency.py [--sigmas 0.35 0.7 1.0] [--seeds 0 1] [--every 10] [--draws 200]
        [--filter JSON]

About a minute per pixel noise.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from feature_information import USED
from pose_linearisation import D12, M, _whitened, drive_updates, perturbed, sampled_updates

AXES = ("ψ12", "dt12", "ψ13", "dt13")


def posterior_nees(uv_true: np.ndarray, poses_true: tuple, Sigma: np.ndarray, cal: tuple, sigma: float,
                   draws: int, rng, noise_at_true: bool) -> np.ndarray:
    """(12,) mean over draws of ``e1_i^2 / Sigma+_ii`` after one update (module docstring) of the
    features uv_true (F, 3, 2) px about the true (R12, t12, R13, t13), the prior Sigma (12, 12) and
    the true (fx, fy, cx, cy); R_f at the true pixels with noise_at_true."""
    F = len(uv_true)
    e0 = rng.multivariate_normal(np.zeros(D12), Sigma, size=draws)
    noisy = uv_true[None] + sigma * rng.standard_normal((draws, F, 3, 2))
    Y, JW, LD = np.empty((draws, 1, F, M)), np.empty((draws, 1, F, M, D12)), np.empty((draws, 1, F))
    clean = np.ascontiguousarray(np.broadcast_to(uv_true[None], noisy.shape))
    _whitened(noisy, *perturbed(*poses_true, e0), np.array([cal], float), sigma, USED, Y, JW, LD,
              clean if noise_at_true else None)
    A = np.einsum("dfac,dfae->dce", JW[:, 0], JW[:, 0])
    beta = np.einsum("dfac,dfa->dc", JW[:, 0], Y[:, 0])
    gain = np.linalg.solve(np.eye(D12)[None] + A @ Sigma, np.concatenate([beta[..., None], A @ Sigma], axis=-1))
    delta = (Sigma @ gain[..., :1])[..., 0]
    post = Sigma[None] - Sigma[None] @ gain[..., 1:]
    return ((e0 - delta) ** 2 / np.diagonal(post, axis1=1, axis2=2)).mean(axis=0)


def measure(seeds, sigma: float, sim: dict, every: int, draws: int, seed: int = 0,
            filter_options: dict | None = None) -> dict:
    """Per noise-model variant ("measured", "true" pixels) the (12,) posterior NEES per axis over
    every ``every``-th update of one fresh drive per camera in seeds (the filter with FilterConfig
    overrides filter_options gives each update's Sigma)."""
    rng = np.random.default_rng(seed)
    out = {"measured": [], "true": []}
    for s in seeds:
        camera, ((_, _, res), (clean, prep, res0)) = drive_updates(s, 0, sigma, sim, filter_options)
        cal = (camera.fx_px[0], camera.fy_px[0], camera.cx_px[0], camera.cy_px[0])
        for k, uv, true in sampled_updates(np.nonzero(res.dof[0] > 0)[0][::every], camera, clean, prep, res0):
            for key in out:
                out[key].append(posterior_nees(uv, true, res.pose_cov[0, k], cal, sigma, draws, rng,
                                               key == "true"))
    return {key: np.mean(v, axis=0) for key, v in out.items()}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.35, 0.7, 1.0], help="pixel noise, px")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="cameras (one fresh drive each)")
    parser.add_argument("--every", type=int, default=10, help="every n-th update frame")
    parser.add_argument("--draws", type=int, default=200, help="draws per update")
    parser.add_argument("--filter", type=json.loads, default=None,
                        help='FilterConfig overrides as JSON, e.g. \'{"imu_noise_scale": 0.1}\' (a tighter prior Sigma)')
    args = parser.parse_args(argv)
    sim = {"imu_noise_on": False, "outlier_fraction": 0}
    print(f"exact IMU, no outliers; filter {args.filter or 'default'}; cameras {args.seeds}, every {args.every}th "
          f"update, {args.draws} draws: the "
          "posterior NEES per axis after one update from a consistent prior (camera 1's x right, y down, z forward)")
    print("| σ (px) | R_f at | " + " | ".join(AXES) + " |\n|---|---|---|---|---|---|")
    for sigma in args.sigmas:
        m = measure(args.seeds, sigma, sim, args.every, args.draws, filter_options=args.filter)
        for key, v in m.items():
            print(f"| {sigma:g} | {key} pixels | " + " | ".join(", ".join(f"{x:.2f}" for x in v[a:a + 3])
                                                             for a in range(0, 12, 3)) + " |", flush=True)


if __name__ == "__main__":
    main()
