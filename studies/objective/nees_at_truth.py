"""Is the filter's state consistent at the true calibration? Position, orientation and velocity NEES per axis
over the drive's quarters, and the relative pose's NEES at the trifocal updates, on fresh drives, each
with its interval over drives (issue 33: where the scores' cross-lag excess comes from).

At the truth a consistent filter's normalised estimation error squared, per axis
``(x_est - x_true)^2 / sigma^2`` with sigma the filter's own standard deviation, averages 1 over
drives. Orientation errors are taken as the filter injects them (docs/model.md, Eq. 8):
``R_est = R_true Exp(dtheta)``, so ``dtheta = Log(R_true^T R_est)`` is in the IMU frame (x forward,
y left, z up: roll, pitch, yaw on a level drive). A NEES well above 1 on an axis means the filter
believes it knows that axis better than it does; an error that outlives many updates correlates
the likelihood's scores across them (studies/objective/score_lags.py).

The relative pose at each update (``FilterResult.pose_cov``, ``update_poses``): the errors of the
clones' relative pose ``[psi12, dt12, psi13, dt13]`` over the diagonal of the update's own
``Sigma = C P C^T`` and of the one-frame prediction ``[psi23, dt23]`` (clone k-1 to the predicted
frame k; studies/objective/pose_linearisation.py), in camera 1's frame (x right, y down, z forward).

**How sure**: a filter's error outlives hundreds of frames, so the frames of one drive are not
independent draws: a drive is the unit. Each figure is the mean over drives of the drive's own
mean, with a 95 % bootstrap interval over drives (scipy.stats.bootstrap, BCa); one drive with a
long excursion can carry the mean of twenty.

    python studies/objective/nees_at_truth.py [--seeds 0 1] [--drives 10] [--sim JSON] [--filter JSON]

About 3 s of CPU per drive (one filter of a 78 s drive at batch 1).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import bootstrap

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from objective_bias import DRIVE, FRESH_SEED0
from pose_linearisation import pose_error, prediction_error, relative_poses
from score_lags import sim_config

from avio.filter.batch import run
from avio.sim.simulator import simulate
from bench.problems.synthetic import Synthetic

AXES = ("px", "py", "pz", "roll", "pitch", "yaw", "vx", "vy", "vz")


def normalised_errors(p_est: np.ndarray, R_est: np.ndarray, p_true: np.ndarray, R_true: np.ndarray,
                      sigma: np.ndarray, v_est: np.ndarray | None = None, v_true: np.ndarray | None = None) -> np.ndarray:
    """(N, 6) squared errors over the filter's variances: position (world, m) then the IMU-frame
    rotation error dtheta = Log(R_true^T R_est) (rad); with v_est, v_true (N, 3) also the velocity
    (world, m/s): (N, 9). p (N, 3), R (N, 3, 3) R_world_imu, sigma (N, >= 9) the filter's standard
    deviations in the error state's order (Eq. 8: p, theta, v, ...)."""
    dtheta = Rotation.from_matrix(np.einsum("nji,njk->nik", R_true, R_est)).as_rotvec()
    parts = [p_est - p_true, dtheta] + ([] if v_est is None else [v_est - v_true])
    error = np.concatenate(parts, axis=1)
    return (error / sigma[:, :error.shape[1]]) ** 2


def relative_pose_nees(res, drive, camera) -> np.ndarray:
    """(18,) one drive's mean squared error over the claimed variance at its trifocal updates, per
    axis: ``[psi12, dt12, psi13, dt13]`` (over the diagonal of the update's Sigma) then the one-frame
    prediction ``[psi23, dt23]``, each (x, y, z) in camera 1's frame; res a FilterResult of one filter
    run with ``record_used`` (its pose_cov, update_poses), drive its sequence, camera the true
    Calibration (batch of 1)."""
    Rci, pic = camera.R_cam_imu[0], camera.p_imu_cam_m[0]
    frames = np.nonzero(res.dof[0] > 0)[0]
    poses = res.update_poses[0, frames]
    est = relative_poses(poses[:, :, :3, :], poses[:, :, 3, :], Rci, pic)
    idx = frames[:, None] + np.array([-2, -1, 0])
    true = relative_poses(drive.truth.R_world_imu[idx], drive.truth.p_world_imu_m[idx], Rci, pic)
    Sig = res.pose_cov[0, frames]
    clones = pose_error(est, true) ** 2 / np.diagonal(Sig, axis1=1, axis2=2)
    return np.concatenate([clones.mean(axis=0), prediction_error(est, true, Sig).mean(axis=0)])


def measure(seeds, n_drives: int, sim: dict | None, filter_options: dict | None
            ) -> tuple[np.ndarray, np.ndarray, int]:
    """Over fresh drives of each seed's camera (the drives of studies/objective/information_equality.py)
    at the true calibration: (D, N, 9) normalised squared errors of the state per frame, (D, 18)
    each drive's relative-pose NEES at its updates (:func:`relative_pose_nees`), and the number of
    drives skipped because the filter diverged."""
    config = sim_config(sim)
    out, rel, skipped = [], [], 0
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local",
                            filter={"outlier_decisions": "reference_all", **(filter_options or {})})
        camera = problem.sequence.truth_calibration
        truth = problem.calibration_space.decode(problem.truth[None])
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=camera)
            res = run(drive, truth, problem.filter_config, prepared=problem.prepared(drive), record_used=True)
            if res.diverged[0]:
                skipped += 1
                continue
            out.append(normalised_errors(res.p_world_imu_m[0], res.R_world_imu[0], drive.truth.p_world_imu_m,
                                         drive.truth.R_world_imu, res.sigma[0], res.v_world_imu_mps[0],
                                         drive.truth.v_world_imu_mps))
            rel.append(relative_pose_nees(res, drive, camera))
    return np.array(out), np.array(rel), skipped


def interval(per_drive: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """(mean, low, high): the mean of the drives' values (D,) and its bootstrap interval over
    drives (BCa, 2,000 resamples, fixed seed); the mean at both ends where the drives cannot
    give one (fewer than 3, or all equal)."""
    per_drive = np.asarray(per_drive, float)
    mean = float(per_drive.mean())
    if per_drive.size < 3 or np.ptp(per_drive) == 0:
        return mean, mean, mean
    ci = bootstrap((per_drive,), np.mean, confidence_level=confidence, n_resamples=2000, method="BCa",
                   random_state=0).confidence_interval
    return mean, float(ci.low), float(ci.high)


def _cell(per_drive: np.ndarray) -> str:
    m, lo, hi = interval(per_drive)
    return f"{m:.2f} [{lo:.2f}–{hi:.2f}]"


def report(e2: np.ndarray, parts: int = 4) -> list[str]:
    """Mean NEES per axis in each of the drive's ``parts`` time slices and over the whole drive
    (the last row, "all"): each drive's mean over the slice's frames, then the mean over drives with
    its interval (:func:`interval`)."""
    N = e2.shape[1]
    edges = np.linspace(0, N, parts + 1).astype(int)
    axes = AXES[:e2.shape[-1]]
    lines = ["| frames | " + " | ".join(axes) + " |", "|---" * (len(axes) + 1) + "|"]
    for a, b in zip(list(edges[:-1]) + [0], list(edges[1:]) + [N]):
        per_drive = e2[:, a:b].mean(axis=1)
        label = "all" if b - a == N else f"{a}–{b - 1}"
        lines.append(f"| {label} | " + " | ".join(_cell(per_drive[:, j]) for j in range(len(axes))) + " |")
    return lines


def report_relative(rel: np.ndarray) -> list[str]:
    """The relative pose's NEES per axis (:func:`relative_pose_nees`, (D, 18)), mean over drives with
    its interval, one row per block."""
    lines = ["| at the updates | x (right) | y (down) | z (forward) |", "|---|---|---|---|"]
    for k, name in enumerate(("psi12", "dt12", "psi13", "dt13", "psi23 (one-frame prediction)", "dt23")):
        lines.append(f"| {name} | " + " | ".join(_cell(rel[:, 3 * k + j]) for j in range(3)) + " |")
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="cameras (data seeds)")
    parser.add_argument("--drives", type=int, default=10, help="fresh drives per camera")
    parser.add_argument("--sim", type=json.loads, default=None, help="SimConfig overrides as JSON (as score_lags.py)")
    parser.add_argument("--filter", type=json.loads, default=None, help="FilterConfig overrides as JSON")
    args = parser.parse_args(argv)
    e2, rel, skipped = measure(args.seeds, args.drives, args.sim, args.filter)
    print(f"{DRIVE}, sim {args.sim or 'default'}, filter {args.filter or 'default'}: cameras {args.seeds}, "
          f"{args.drives} fresh drives each ({skipped} skipped: diverged); NEES per axis (1 is consistent), "
          "mean over drives [95 % bootstrap interval over drives]")
    print("\n".join(report(e2)))
    print()
    print("\n".join(report_relative(rel)))


if __name__ == "__main__":
    main()
