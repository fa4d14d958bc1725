"""Is the filter's state consistent at the true calibration? Position, orientation and velocity NEES per axis
over the drive's quarters, on fresh drives (issue 33: where the scores' cross-lag excess comes from).

At the truth a consistent filter's normalised estimation error squared, per axis
``(x_est - x_true)^2 / sigma^2`` with sigma the filter's own standard deviation, averages 1 over
drives. Orientation errors are taken as the filter injects them (docs/model.md, Eq. 8):
``R_est = R_true Exp(dtheta)``, so ``dtheta = Log(R_true^T R_est)`` is in the IMU frame (x forward,
y left, z up: roll, pitch, yaw on a level drive). A NEES well above 1 on an axis means the filter
believes it knows that axis better than it does; an error that outlives many updates correlates
the likelihood's scores across them (studies/objective/score_lags.py).

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

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from objective_bias import DRIVE, FRESH_SEED0
from score_lags import sim_config

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


def measure(seeds, n_drives: int, sim: dict | None, filter_options: dict | None) -> tuple[np.ndarray, int]:
    """(D, N, 6) normalised squared errors at the true calibration over fresh drives of each
    seed's camera (the drives of studies/objective/information_equality.py), and the number of
    drives skipped because the filter diverged."""
    config = sim_config(sim)
    out, skipped = [], 0
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local",
                            filter={"outlier_decisions": "reference_all", **(filter_options or {})})
        truth = problem.calibration_space.decode(problem.truth[None])
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=problem.sequence.truth_calibration)
            res = problem.run_filter(truth, drive)
            if res.diverged[0]:
                skipped += 1
                continue
            out.append(normalised_errors(res.p_world_imu_m[0], res.R_world_imu[0], drive.truth.p_world_imu_m,
                                         drive.truth.R_world_imu, res.sigma[0], res.v_world_imu_mps[0],
                                         drive.truth.v_world_imu_mps))
    return np.array(out), skipped


def report(e2: np.ndarray, parts: int = 4) -> list[str]:
    """Mean NEES per axis over drives and frames in each of the drive's ``parts`` time slices."""
    N = e2.shape[1]
    edges = np.linspace(0, N, parts + 1).astype(int)
    axes = AXES[:e2.shape[-1]]
    lines = ["| frames | " + " | ".join(axes) + " |", "|---" * (len(axes) + 1) + "|"]
    for a, b in zip(edges[:-1], edges[1:]):
        lines.append(f"| {a}–{b - 1} | " + " | ".join(f"{v:.2f}" for v in e2[:, a:b].mean(axis=(0, 1))) + " |")
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="cameras (data seeds)")
    parser.add_argument("--drives", type=int, default=10, help="fresh drives per camera")
    parser.add_argument("--sim", type=json.loads, default=None, help="SimConfig overrides as JSON (as score_lags.py)")
    parser.add_argument("--filter", type=json.loads, default=None, help="FilterConfig overrides as JSON")
    args = parser.parse_args(argv)
    e2, skipped = measure(args.seeds, args.drives, args.sim, args.filter)
    print(f"{DRIVE}, sim {args.sim or 'default'}, filter {args.filter or 'default'}: cameras {args.seeds}, "
          f"{args.drives} fresh drives each ({skipped} skipped: diverged); NEES per axis (1 is consistent)")
    print("\n".join(report(e2)))


if __name__ == "__main__":
    main()
