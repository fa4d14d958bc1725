"""The innovation likelihood's slope at the truth along one variable, split into its parts.

studies/objective/objective_bias.py finds one significant slope of ``innovation_nll`` at the truth, along
fy. This script measures it on fresh drives of the study's 5 cameras (as objective_bias.py
builds them: data seed s, drives ``(s, 100 + i)``) for the truth +- one step along ``--var``,
and prints the mean slope over the drives (+- SE, t) of:

- ``composite``: the objective (avio/objectives.py: per-feature marginal likelihoods, capped);
- ``joint``: the joint likelihood of the updates over the features they used, per residual,
  ``1/2 (sum_k NIS_k + sum_k log det S_k) / sum_k m_k`` over the scored frames
  (FilterResult.nis, log_det_S, dof), and its two parts ``joint_nis`` and ``joint_ldS``;
- ``used``: the number of residuals the updates used (whether the step changes the gate's
  decisions).

A log det part that is the same on every kind of data and a NIS part that balances it only
with some noise sources say where the tilt comes from (studies/objective/README.md: "The likelihood has one small
deterministic tilt, along fy").

    python studies/objective/likelihood_tilt.py [--noise default|pixel|imu|none] [--drives 16] [--var fy]
        [--step 0.5] [--filter '{"imu_noise_scale": 1.4}'] [--sim '{"gyro_bias_radps": [0, 0, 0]}']
        [--imu-scale 2]

**The terms** (``--terms``; issue 33: which term of the joint likelihood's score tilts it?).
Each update's joint NLL is ``l = 1/2 (r^T S^-1 r + log det S)`` (docs/model.md, Eq. 55a) with the
residuals r and ``S = J Sigma J^T + R`` taken at the filter's estimated relative poses. Along one
intrinsic theta its total derivative (each calibration its own filter run) splits exactly into

- ``A = 1/2 d log det S``: the model's variance growing with theta;
- ``B = -1/2 r^T S^-1 dS S^-1 r``: the NIS's answer to it; ``E[B] = -E[A]`` where the residuals'
  covariance is S in the directions dS weights;
- ``C = dr^T S^-1 r``: the residuals' own change correlated with them; ``E[C] = 0`` where the
  innovations are zero-mean given the past (dr is a function of the past and of the calibration).

C is then split by where dr is taken: ``C_direct`` (the intrinsics moved, this run's estimated
poses held) and ``C_reach`` (the poses moved to the other runs', the intrinsics held); and
C_direct's dr taken instead at the noise-free pixels (the drive simulated again without pixel
noise: does the pixels' noise make it?), at the true poses (does the pose estimate's error make
it?), and at the true poses but for one block of the relative pose's error (psi12, dt12 per axis,
psi13, dt13 per axis; which error?). Each with the residuals r and S of the truth run.

``--predict`` adds C_direct's pose share as the filter's own quantities predict it: with the
estimate's relative-pose error d (r at the estimate = r at the truth + J d) and
``M = d(dr)/dd``, ``E[(M d)^T S^-1 J d] = tr(M^T S^-1 J Sigma)`` where Sigma is the error's
covariance (the filter's claim). It is not zero even for a consistent filter: the likelihood is
exact when the trajectory is random about the estimate, while a drive has one fixed trajectory
and the estimate is what is random. ``adjustment`` is the derivative of
``1/2 tr(S^-1 R) = m/2 - 1/2 tr(J^T S^-1 J Sigma)`` (each run its own S, J, Sigma), whose
J-part cancels that share: the candidate correction of the likelihood.

Fresh ``paper_540m`` drives (cameras ``--seeds``, drives ``(s, 100 + i)``), imposed decisions
(``reference_all``), the filter's measured-pixel Jacobians unless ``--filter`` says otherwise
(the reconstruction re-computes the default kernel's update NLL; it prints the largest difference),
central differences of information_equality.py's steps (1.5 px, 0.15 deg, 1.5 cm). An extrinsic
variable moves the cameras' poses only: its C is all C_reach (C_direct and its splits are 0). Per drive the terms summed over the update frames; printed: the
mean over drives, its SE, t and the signed-rank p.

    python studies/objective/likelihood_tilt.py --terms [--seeds 0 1 2 3 4] [--drives 4] [--var fy] [--sim JSON]
        [--filter JSON] [--every 1] [--predict] [--save F.npz]

About 20 s of CPU per drive. Results: studies/objective/README.md, "the fy tilt's term".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from feature_information import USED
from information_equality import STEP
from objective_bias import DRIVE, FRESH_SEED0, NOISE, mean_se
from pose_linearisation import _problem, perturbed, pose_error, relative_poses
from scipy.stats import wilcoxon
from score_lags import sim_config

from avio.filter.batch import run, set_threads
from avio.filter.prepare import prepare
from avio.filter.trifocal import feature_residuals
from avio.filter.update import NOISE_FLOOR
from avio.objectives import scored_frames
from avio.sequence import ImuNoise
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import Synthetic

PARTS = ("composite", "joint", "joint_nis", "joint_ldS", "used")
#: besides the slopes, the objective's curvature along the variable (per unit^2)
CURVATURE = "composite_curvature"


def slopes(noise: str, n_drives: int, var: str, step: float, filter_overrides: dict | None,
           seeds=range(5), sim_overrides: dict | None = None, tie_focal: bool = False) -> dict[str, np.ndarray]:
    """Per part, the (len(seeds) * n_drives,) central-difference slopes at the truth along var
    (sim_overrides: SimConfig fields over the noise setting's; tie_focal: fy = fx, so ``fx`` is
    the common focal length), and the objective's curvature (CURVATURE)."""
    out = {k: [] for k in (*PARTS, CURVATURE)}
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local", filter=filter_overrides,
                            tie_focal=tie_focal)
        camera = problem.sequence.truth_calibration
        j = problem.space.names.index(var)
        x = np.stack([problem.truth + d * np.eye(len(problem.truth))[j] for d in (-step, 0.0, step)])
        batch = problem.calibration_space.decode(x)
        config = getattr(SimConfig, DRIVE)(**{**NOISE[noise], **(sim_overrides or {})})
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=camera)
            res = problem.run_filter(batch, drive)
            scored = scored_frames(drive)
            dof = np.where(scored, res.dof, 0).sum(axis=1)
            nis = np.where(scored, res.nis, 0.0).sum(axis=1) / dof
            lds = np.where(scored, res.log_det_S, 0.0).sum(axis=1) / dof
            vals = {"composite": np.where(scored, res.nll, 0.0).sum(axis=1) / np.where(scored, res.nll_slots, 0).sum(axis=1),
                    "joint": 0.5 * (nis + lds), "joint_nis": 0.5 * nis, "joint_ldS": 0.5 * lds,
                    "used": dof.astype(float)}
            for k, v in vals.items():
                out[k].append((v[2] - v[0]) / (2 * step))
            c = vals["composite"]
            out[CURVATURE].append((c[2] + c[0] - 2 * c[1]) / step**2)
    return {k: np.array(v) for k, v in out.items()}


#: the relative pose's error blocks (pose_error's order: psi12, dt12, psi13, dt13)
BLOCKS = {"psi12": [0, 1, 2], "dt12_x": [3], "dt12_y": [4], "dt12_z": [5], "psi13": [6, 7, 8],
          "dt13_x": [9], "dt13_y": [10], "dt13_z": [11]}
TERMS = ("A", "B", "C", "C_direct", "C_reach", "C_direct_clean_pixels", "C_direct_true_poses",
         "C_direct_r_noise", "C_direct_r_pose", "C_direct_r_pose_linear",
         *(f"C_direct_error_{b}" for b in BLOCKS), "kernel_total", "adjustment", "C_direct_predicted")


def residuals(uv: np.ndarray, poses: tuple, intrinsics: np.ndarray, sigma: float,
              Sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The update's used residuals r (m F,), ``S = J Sigma J^T + R`` (m F, m F) and J (m F, 12) of the features
    uv (F, 3, 2) at the relative poses (R12, t12, R13, t13; Eq. 21) and intrinsics (fx, fy, cx, cy),
    R block-diagonal over features (Eq. 35, at uv)."""
    R12, t12, R13, t13 = poses
    R23, t23 = R12.T @ R13, R12.T @ (t13 - t12)
    r4, J4, G4 = np.empty(4), np.empty((4, 12)), np.empty((4, 6))
    m, F = len(USED), len(uv)
    r, J, R = np.empty(m * F), np.empty((m * F, 12)), np.zeros((m * F, m * F))
    for f in range(F):
        feature_residuals(uv[f], R12, tuple(t12), R13, tuple(t13), R23, tuple(t23), *intrinsics, r4, J4, G4, False)
        rows = slice(f * m, (f + 1) * m)
        r[rows], J[rows] = r4[USED], J4[USED]
        G = G4[USED]
        R[rows, rows] = sigma**2 * (G @ G.T) + (NOISE_FLOOR * sigma) ** 2 * np.eye(m)
    return r, R + J @ Sigma @ J.T, J


def drive_terms(seed: int, index: int, var: str, sim: dict, filter_options: dict,
                every: int = 1, predict: bool = False) -> dict[str, float] | None:
    """Per term (TERMS), its sum over the update frames of one fresh drive (every ``every``-th); the
    reconstruction's largest difference from the kernel's update NLL (``check``); None when a
    filter diverged."""
    sigma = float(filter_options.get("pixel_sigma_px", 0.7))
    problem = _problem(seed, sigma, {k: v for k, v in filter_options.items() if k != "pixel_sigma_px"})
    camera, cfg = problem.sequence.truth_calibration, problem.filter_config
    j = problem.space.names.index(var)
    x = np.repeat(problem.truth[None], 3, axis=0)
    x[0, j] -= STEP[var]
    x[2, j] += STEP[var]
    batch = problem.calibration_space.decode(x)
    rows = np.stack([batch.fx_px, batch.fy_px, batch.cx_px, batch.cy_px], axis=1)  # (3, 4) intrinsics
    drive = simulate(sim_config({**sim, "pixel_noise_px": sim.get("pixel_noise_px", 0.7)}),
                     (seed, FRESH_SEED0 + index), true_calibration=camera)
    clean = simulate(sim_config({**sim, "pixel_noise_px": 0.0}), (seed, FRESH_SEED0 + index), true_calibration=camera)
    prep = prepare(drive, cfg)
    res = run(drive, batch, cfg, prepared=prep, record_used=True)
    if res.diverged.any():
        return None
    Rci, pic = camera.R_cam_imu[0], camera.p_imu_cam_m[0]
    ext = [(batch.R_cam_imu[p], batch.p_imu_cam_m[p]) for p in range(3)]  # each run's extrinsic
    noisy_tracks, clean_tracks = drive.tracks.uv_px, clean.tracks.uv_px
    trip_of = {int(k): j for j, k in enumerate(drive.tracks.frame_index)}
    out = dict.fromkeys([t for t in TERMS if predict or t != "C_direct_predicted"], 0.0)
    check = 0.0
    h2 = 2 * STEP[var]

    def q(r, S):
        return 0.5 * r @ np.linalg.solve(S, r)

    def ld(S):
        return 0.5 * np.linalg.slogdet(S)[1]

    for k in np.nonzero(res.dof[1] > 0)[0][::every]:
        uv = prep.uv_px[prep.triplet_of_frame[k]][res.used[1, prep.triplet_of_frame[k]]]
        # the same features' noise-free pixels: the prepared slots matched to the drive's tracks
        tj = trip_of[int(k)]
        match = [int(np.nonzero(np.all(noisy_tracks[tj] == u, axis=(1, 2)))[0][0]) for u in uv]
        uv_clean = clean_tracks[tj][match]
        est = [relative_poses(res.update_poses[p, k][:, :3, :], res.update_poses[p, k][:, 3, :], *ext[p])
               for p in range(3)]
        t3 = k + np.array([-2, -1, 0])
        true = relative_poses(drive.truth.R_world_imu[t3], drive.truth.p_world_imu_m[t3], Rci, pic)
        delta = pose_error(est[1], true)

        def at(p_int, poses, p_cov=1, pixels=uv):
            return residuals(pixels, poses, rows[p_int], sigma, res.pose_cov[p_cov, k])

        (rm, Sm, _), (r1, S1, J1), (rp, Sp, _) = at(0, est[0], 0), at(1, est[1]), at(2, est[2], 2)
        r_true = at(1, true)[0]  # the residuals at the true poses: the pixels' noise alone
        w = np.linalg.solve(S1, r1)

        def dr(poses, pixels=uv):  # the residuals' derivative along var, this run's Sigma
            return (at(2, poses, pixels=pixels)[0] - at(0, poses, pixels=pixels)[0]) / h2

        def half_tr_Sinv_R(r_S_J, p_cov):  # 1/2 tr(S^-1 R) = m/2 - 1/2 tr(S^-1 J Sigma J^T)
            _, S, J = r_S_J
            return 0.5 * np.trace(np.linalg.solve(S, S - J @ res.pose_cov[p_cov, k] @ J.T))

        terms = {"adjustment": (half_tr_Sinv_R(at(2, est[2], 2), 2) - half_tr_Sinv_R(at(0, est[0], 0), 0)) / h2,
                 "A": (ld(Sp) - ld(Sm)) / h2, "B": (q(r1, Sp) - q(r1, Sm)) / h2, "C": (q(rp, S1) - q(rm, S1)) / h2,
                 "C_direct": dr(est[1]) @ w, "C_reach": (at(1, est[2])[0] - at(1, est[0])[0]) / h2 @ w,
                 "C_direct_clean_pixels": dr(est[1], uv_clean) @ w, "C_direct_true_poses": dr(true) @ w}
        # C_direct split by the residuals' parts: the pixels' noise, the pose error's, and that
        # part to first order (J's convention: dr = -J d, d = pose_error's true - estimate)
        Sinv_dr = np.linalg.solve(S1, dr(est[1]))
        terms |= {"C_direct_r_noise": Sinv_dr @ r_true, "C_direct_r_pose": Sinv_dr @ (r1 - r_true),
                  "C_direct_r_pose_linear": Sinv_dr @ (J1 @ delta)}
        if predict:  # C_direct's pose share from the filter's own Sigma: tr(M^T S^-1 J Sigma), M = d(dr)/d(pose)
            M = np.empty((len(r1), 12))
            for c in range(12):
                step = np.zeros(12)
                step[c] = 1e-4
                up, down = (perturbed(*est[1], (sgn * step)[None]) for sgn in (1.0, -1.0))
                M[:, c] = (dr(tuple(a[0] for a in up[:4])) - dr(tuple(a[0] for a in down[:4]))) / 2e-4
            terms["C_direct_predicted"] = float(np.trace(M.T @ np.linalg.solve(S1, J1 @ res.pose_cov[1, k])))
        for name, idx in BLOCKS.items():
            mask = np.zeros(12)
            mask[idx] = 1.0
            one = perturbed(*true, (delta * mask)[None])
            terms[f"C_direct_error_{name}"] = dr(tuple(a[0] for a in one[:4])) @ w
        kernel = 0.5 * (res.nis[:, k] + res.log_det_S[:, k])
        terms["kernel_total"] = (kernel[2] - kernel[0]) / h2
        check = max(check, abs(q(r1, S1) + ld(S1) - kernel[1]))
        for name, v in terms.items():
            out[name] += float(v)
    out["check"] = check
    return out


def terms_main(args) -> None:
    """``--terms``: the per-drive terms (TERMS) on fresh drives, their mean, SE, t and signed-rank p."""
    args.sim, args.filter = args.sim or {}, args.filter or {}
    per_drive = [t for s in args.seeds for i in range(args.drives)
                 if (t := drive_terms(s, i, args.var, args.sim, args.filter, args.every, args.predict)) is not None]
    if args.save:
        np.savez(args.save, **{k: np.array([d[k] for d in per_drive]) for k in (*TERMS, "check") if k in per_drive[0]})
    print(f"sim {args.sim or 'default'}, filter {args.filter or 'default'}: {len(per_drive)} drives, d/d{args.var} "
          f"(nats per px per drive); reconstruction's largest difference {max(d['check'] for d in per_drive):.1e} nats")
    print("| term | mean | SE | t | signed-rank p |\n|---|---|---|---|---|")
    for k in TERMS:
        if k not in per_drive[0]:
            continue
        x = np.array([d[k] for d in per_drive])
        se = x.std(ddof=1) / np.sqrt(len(x))
        print(f"| {k} | {x.mean():+.4f} | {se:.4f} | {x.mean() / se:+.1f} | {wilcoxon(x).pvalue:.2g} |")


def scaled_imu_noise(scale: float) -> ImuNoise:
    """The simulator's default ImuNoise with every density times ``scale``."""
    return ImuNoise(**{f.name: scale * getattr(ImuNoise(), f.name) for f in fields(ImuNoise)})


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", choices=list(NOISE), default="default")
    parser.add_argument("--drives", type=int, default=16, help="fresh drives per camera")
    parser.add_argument("--var", default="fy", help="local-space variable (fx, fy, cx, cy, rx, ..., dz)")
    parser.add_argument("--step", type=float, default=0.5, help="central-difference step in the variable's unit")
    parser.add_argument("--filter", type=json.loads, default=None, help="FilterConfig overrides as JSON")
    parser.add_argument("--sim", type=json.loads, default=None,
                        help='SimConfig overrides as JSON, e.g. \'{"gyro_bias_radps": [0, 0, 0]}\'')
    parser.add_argument("--tie-focal", action="store_true", help="fy = fx (the problem's tie_focal); --var fx is then both")
    parser.add_argument("--imu-scale", type=float, default=1.0,
                        help="multiply the simulated IMU noise densities (the filter's process noise follows: it "
                             "takes the drive's ImuNoise)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--terms", action="store_true",
                        help="split the joint likelihood's score per update into its terms (module docstring; "
                             "--var any variable, information_equality.py's steps, --step unused)")
    parser.add_argument("--every", type=int, default=1, help="--terms: every n-th update frame only")
    parser.add_argument("--predict", action="store_true",
                        help="--terms: also C_direct's pose share predicted from the filter's own Sigma (~3x the CPU)")
    parser.add_argument("--save", type=Path, help="--terms: write the per-drive terms (.npz)")
    args = parser.parse_args(argv)
    if args.terms:
        if args.var not in STEP:
            parser.error(f"--var {args.var!r}: with --terms one of {', '.join(STEP)}")
        set_threads(1)
        terms_main(args)
        return
    set_threads(2)
    start = time.perf_counter()
    sim = dict(args.sim or {})
    if args.imu_scale != 1.0:
        sim["imu_noise"] = scaled_imu_noise(args.imu_scale)
    result = slopes(args.noise, args.drives, args.var, args.step, args.filter, args.seeds, sim or None, args.tie_focal)
    n = len(result["joint"])
    print(f"{args.noise}, sim {args.sim or 'default'}, IMU noise x{args.imu_scale:g}, filter {args.filter or 'default'}: slope along {args.var} at the truth per unit, "
          f"mean over {n} drives +- SE (t) ({time.perf_counter() - start:.0f} s)")
    for k in PARTS:
        m, se = mean_se(result[k])
        t = f"{m / se:+6.1f}" if se > 0 else "     -"
        print(f"  {k:>10}: {m:+.3e} +- {se:.2e} ({t})")
    slope, slope_se = mean_se(result["composite"])
    curv, curv_se = mean_se(result[CURVATURE])
    if curv > 2 * curv_se:  # the implied 1-D minimum of the mean objective, only where it is clearly curved
        print(f"  objective's curvature {curv:+.3e} +- {curv_se:.2e} per unit^2: its mean's 1-D minimum lies "
              f"{-slope / curv:+.3g} +- {slope_se / curv:.2g} from the truth")
    else:
        print(f"  objective's curvature {curv:+.3e} +- {curv_se:.2e} per unit^2: not clearly positive (flat along {args.var})")


if __name__ == "__main__":
    main()
