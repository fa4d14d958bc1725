"""Does evo agree with our trajectories? evo's APE on the exported files against our position RMSE.

    python studies/data_checks/check_evo.py JOB_DIR [--calibration best|reference|truth] [--drive calibration|holdout]

Exports the job's trajectories with ``python -m bench.export`` (TUM and KITTI), reads them back
with evo's own readers and prints evo's absolute pose error (translation part, no alignment, no
scale correction: ``evo_ape tum GT EST`` defaults) against the position RMSE our metrics give
(``avio.metrics.pose_errors``), and the difference. evo is an optional extra, not a dependency:
``pip install 'avio-bench[evo]'`` (or ``pip install 'evo>=1.28'``); without it the script says
so and exits 0 without checking anything.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("job_dir", type=Path, help="a finished job folder of a VIO problem")
    parser.add_argument("--calibration", default="best", choices=("best", "reference", "truth"))
    parser.add_argument("--drive", default="calibration", choices=("calibration", "holdout"))
    args = parser.parse_args(argv)
    try:
        from evo.core import metrics
        from evo.tools import file_interface
    except ImportError:
        print("evo is not installed: pip install 'avio-bench[evo]' (or pip install 'evo>=1.28'); skipping the check")
        return 0
    from bench.report.export import ExportArgsError, check_job, export

    try:
        check_job(args.job_dir, args.calibration, args.drive)
    except ExportArgsError as err:
        print(f"check_evo: error: {err}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for fmt in ("tum", "kitti"):
            done = export(args.job_dir, args.calibration, fmt, args.drive, Path(tmp) / fmt)
            est, gt = done["files"][:2]
            if fmt == "tum":
                traj_est, traj_gt = file_interface.read_tum_trajectory_file(est), file_interface.read_tum_trajectory_file(gt)
            else:
                traj_est, traj_gt = file_interface.read_kitti_poses_file(est), file_interface.read_kitti_poses_file(gt)
            ape = metrics.APE(metrics.PoseRelation.translation_part)
            ape.process_data((traj_gt, traj_est))
            evo_rmse = ape.get_statistic(metrics.StatisticsType.rmse)
            rows.append((fmt, evo_rmse, done["position_rmse_m"]))
    print(f"{'format':>6} {'evo APE rmse (m)':>20} {'our position RMSE (m)':>22} {'difference (m)':>15}")
    for fmt, evo_rmse, ours in rows:
        print(f"{fmt:>6} {evo_rmse:20.12f} {ours:22.12f} {evo_rmse - ours:15.3e}")
    worst = max(abs(e - o) for _, e, o in rows)
    print(f"largest difference: {worst:.3e} m ({'agree' if worst < 1e-9 else 'DISAGREE'})")
    return 0 if worst < 1e-9 else 1


if __name__ == "__main__":
    sys.exit(main())
