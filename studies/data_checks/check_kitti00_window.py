"""Where the kitti00 928 m window goes wrong: ground-truth yaw rate against the real gyro, and
the filter's position RMSE with the truth calibration on sub-windows.

    python studies/data_checks/check_kitti00_window.py [--around 2686 2700] [--seed 0]
"""

from __future__ import annotations

import argparse

import numpy as np

from avio.datasets.kitti00 import kitti00_truth, load_kitti00, read_kitti00
from avio.filter.batch import run
from avio.metrics import position_rmse_objective
from bench.problems.vio import default_data_dir

SUB_WINDOWS = ((2404, 3553), (2404, 2684), (2710, 3553))


def yaw_rates(data_dir, first: int, last: int) -> None:
    """Ground-truth body yaw rate (finite differences) next to the real gyro z, deg/s."""
    raw, truth = read_kitti00(data_dir), kitti00_truth(data_dir)
    t = raw.frame_t_s
    print(f"{'frame':>6} {'GT yaw rate':>12} {'gyro z':>8}   (deg/s)")
    for k in range(first, last + 1):
        R_rel = truth.R_W_imu[k].T @ truth.R_W_imu[k + 1]
        rate = np.degrees(np.arctan2(R_rel[1, 0], R_rel[0, 0]) / (t[k + 1] - t[k]))
        t_imu = 0.5 * (t[k] + t[k + 1])  # read_kitti00 puts frame times on the IMU clock already
        i = int(np.argmin(np.abs(raw.imu.t_s - t_imu)))
        print(f"{k:6d} {rate:12.1f} {np.degrees(raw.imu.gyro_imu_radps[i, 2]):8.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--around", nargs=2, type=int, default=(2680, 2705))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    data_dir = default_data_dir() / "kitti00"
    yaw_rates(data_dir, *args.around)
    for first, last in SUB_WINDOWS:
        seq = load_kitti00(data_dir, first, last, camera="simulated", seed=args.seed, max_features=30,
                           max_gt_rate_misfit_radps=None)  # this script shows the defect itself
        f = position_rmse_objective(run(seq, seq.truth_calibration), seq.truth)[0]
        print(f"frames {first}-{last} ({seq.path_length_m():.0f} m): position RMSE {f:.2f} m with the truth calibration")


if __name__ == "__main__":
    main()
