"""Export a job's estimated and ground-truth trajectories for evo and other tools.

    python -m bench.export JOB_DIR [--calibration best|reference|truth] --format tum|kitti
                           [--drive calibration|holdout] [--out DIR]

Rebuilds the job's problem from its ``record.json`` config, runs the VIO with the chosen
calibration (the job's best point, the problem's reference, or the truth when known) on the
calibration drive or the held-out drive, and writes into DIR (default ``JOB_DIR/export``):

- TUM: ``<drive>_<calibration>.tum`` and ``<drive>_groundtruth.tum`` (``t tx ty tz qx qy qz qw``,
  t on the IMU clock in seconds);
- KITTI: ``<drive>_<calibration>.kitti`` and ``<drive>_groundtruth.kitti`` (3x4 ``[R|t]`` a line)
  with ``<drive>_times.txt`` (one time a line, s).

The pose is ``T_world_imu`` (``avio.export``). It prints the files and the VIO's position RMSE
against the truth, which evo's APE (translation part, no alignment) reproduces on those files
(``studies/data_checks/check_evo.py``). Bad input (no record, a record that is not a finished VIO job, a
truth the problem does not know) ends with one message and exit code 2 before any work.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from avio.errors import AvioError
from bench.errors import BenchError
from bench.records import RECORD, read_record

CALIBRATIONS = ("best", "reference", "truth")
FORMATS = ("tum", "kitti")
DRIVES = ("calibration", "holdout")


class ExportArgsError(BenchError):
    """The export cannot start; the message names the file or the option."""


class ExportDivergedError(BenchError):
    """The filter diverged with the chosen calibration; nothing was written (exit code 1)."""


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def check_job(job_dir: Path, calibration: str, drive: str = "calibration") -> dict:
    """The job's record, after checking it can be exported with ``calibration`` (no work done)."""
    job_dir = Path(job_dir)
    if not (job_dir / RECORD).is_file():
        raise ExportArgsError(f"{job_dir}: no {RECORD} (not a job folder)")
    record = read_record(job_dir)
    if not isinstance(record, dict) or not isinstance(record.get("config"), dict) \
            or not isinstance(record["config"].get("problem"), dict):
        raise ExportArgsError(f"{job_dir / RECORD}: no problem config in the record")
    from bench.report.paper.tables import _is_vio_problem

    name = record["config"]["problem"].get("name")
    if not _is_vio_problem(str(name)):
        raise ExportArgsError(f"{job_dir / RECORD}: problem {name!r} is not a VIO problem (no trajectory)")
    if calibration == "best" and (record.get("status") != "ok" or record.get("best_x") is None):
        raise ExportArgsError(f"{job_dir / RECORD}: --calibration best needs a finished job with a best point "
                              f"(status {record.get('status')!r})")
    if calibration == "truth" and record.get("truth_x") is None and "truth_x" in record:
        raise ExportArgsError(f"{job_dir / RECORD}: --calibration truth: the problem's truth is unknown")
    identity = record.get("problem_identity")
    if drive == "holdout" and isinstance(identity, dict) and "holdout" in identity and not identity["holdout"]:
        raise ExportArgsError(f"{job_dir / RECORD}: --drive holdout: the problem has no held-out drive")
    return record


def export(job_dir: Path, calibration: str = "best", fmt: str = "tum", drive: str = "calibration",
           out: Path | None = None, log=_say) -> dict:
    """Write the trajectories (see the module doc); return ``{"files": [...], "position_rmse_m": float}``."""
    from avio.export import write_kitti, write_tum
    from avio.metrics import pose_errors
    from bench.problems.base import build_problem

    if calibration not in CALIBRATIONS:
        raise ExportArgsError(f"--calibration must be one of {', '.join(CALIBRATIONS)}, got {calibration!r}")
    if fmt not in FORMATS:
        raise ExportArgsError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    if drive not in DRIVES:
        raise ExportArgsError(f"--drive must be one of {', '.join(DRIVES)}, got {drive!r}")
    job_dir = Path(job_dir)
    record = check_job(job_dir, calibration, drive)
    out = Path(out) if out is not None else job_dir / "export"
    started = time.perf_counter()
    log(f"export: building problem {record['config']['problem'].get('name')!r} from {job_dir / RECORD} "
        "(simulating or loading its drives; compiling the VIO filter on a first run, ~30 s)")
    try:
        problem = build_problem(record["config"])
    except (BenchError, AvioError) as err:  # ProblemError, SpaceError, a data file's DatasetError
        raise ExportArgsError(f"{job_dir / RECORD}: cannot rebuild the problem from the record's config: "
                              f"{err}") from None
    sequence = problem.sequence if drive == "calibration" else problem.holdout
    if sequence is None:
        raise ExportArgsError(f"--drive holdout: problem {problem.name!r} has no held-out drive")
    if calibration == "best":
        cal = problem.calibration_space.decode(np.asarray([record["best_x"]], float))
    elif calibration == "reference":
        cal = sequence.reference_calibration
    else:
        cal = sequence.truth_calibration
        if cal is None:
            raise ExportArgsError(f"--calibration truth: problem {problem.name!r} has no known truth")
    log(f"export: running the VIO on the {drive} drive {sequence.name} ({sequence.n_frames} frames) "
        f"with the {calibration} calibration")
    result = problem.run_filter(cal, sequence)
    if bool(result.diverged[0]):
        raise ExportDivergedError(f"the filter diverged at frame {int(result.diverged_at_frame[0])} with the "
                                  f"{calibration} calibration; nothing written")
    rmse = float(pose_errors(result, sequence.truth)["position_rmse"][0])
    p, R = result.p_world_imu_m[0], result.R_world_imu[0]
    truth = sequence.truth
    stem = f"{drive}_{calibration}"
    if fmt == "tum":
        files = [out / f"{stem}.tum", out / f"{drive}_groundtruth.tum"]
        write_tum(files[0], sequence.frame_t_s, p, R)
        write_tum(files[1], sequence.frame_t_s, truth.p_world_imu_m, truth.R_world_imu)
    else:
        files = [out / f"{stem}.kitti", out / f"{drive}_groundtruth.kitti", out / f"{drive}_times.txt"]
        write_kitti(files[0], p, R)
        write_kitti(files[1], truth.p_world_imu_m, truth.R_world_imu)
        files[2].write_text("".join(f"{t:.9f}\n" for t in sequence.frame_t_s))
    log(f"export: done in {time.perf_counter() - started:.1f} s; position RMSE {rmse:.6f} m")
    return {"files": files, "position_rmse_m": rmse}


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: 0 on success, 2 with one message on bad input, 1 if the filter diverged."""
    parser = argparse.ArgumentParser(prog="python -m bench.export", description=__doc__.splitlines()[0])
    parser.add_argument("job_dir", type=Path, help="a job folder (holding record.json)")
    parser.add_argument("--calibration", choices=CALIBRATIONS, default="best",
                        help="the job's best point (default), the problem's reference, or the truth")
    parser.add_argument("--format", choices=FORMATS, required=True, help="TUM (t x y z qx qy qz qw) or KITTI (3x4)")
    parser.add_argument("--drive", choices=DRIVES, default="calibration", help="which drive (default: calibration)")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: JOB_DIR/export)")
    args = parser.parse_args(argv)
    try:
        done = export(args.job_dir, args.calibration, args.format, args.drive, args.out)
    except ExportDivergedError as err:
        print(f"bench.export: error: {err}", file=sys.stderr)
        return 1
    except (BenchError, AvioError) as err:  # ExportArgsError, RecordError, an avio error running the VIO
        print(f"bench.export: error: {err}", file=sys.stderr)
        return 2
    for path in done["files"]:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
