"""What the paper's tables and figures need from the filter, computed once and stored beside the records.

The report must rebuild in seconds from records alone, but Tables 1–3, the trajectory figures
and the objective profile need the VIO run at the records' calibrations. ``load_or_compute``
runs it once per VIO problem of a sweep and stores the results under
``<sweep>/artifacts/<problem>-<hash>/`` as plain CSV, JSON and ``.npz`` (no pickle: loaded with
``allow_pickle=False``):

- ``manifest.json``: the key (SHA-256 of the artifact schema, the problem's config and every
  finished run's optimizer, seed and best point), the problem's space (names, units, bounds,
  reference, truth and whether the truth lies inside the bounds) and the drives (name, frames,
  path length);
- ``calibrations.csv``: one row per source — ``reference``, ``truth`` (when known) and every
  finished run (``run``, with optimizer, seed, best f) — with its point in the problem's space
  (``x.<name>``), in the paper's Table 1 variables (``paper.<var>``) and its calibration errors
  against the truth (``err.<name>``);
- ``drive_calibration.csv`` / ``drive_holdout.csv``: the same rows with the VIO's position,
  velocity and attitude error RMSE/mean/std and drift (``avio.metrics.drift_metrics``) on that
  drive;
- ``trajectories_<drive>.npz``: frame times ``t_s`` (N,), ``p_true`` (N, 3) m, and for the
  reference, the truth and each optimiser's median run (by best f; ``labels``) the estimated
  positions ``p_est`` (K, N, 3) m and per-frame errors ``e_position`` (m), ``e_velocity``
  (m/s), ``e_attitude`` (deg), each (K, N);
- ``profile.csv``: the objective along each variable (``objective_profile``).

A stored set whose key no longer matches the records (a run added, a config changed) is
recomputed, and so is every set with ``recompute=True``; each computation prints what it does.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from bench.errors import BenchError

SCHEMA = 1
DRIVES = ("calibration", "holdout")
STATES = ("position", "velocity", "attitude")
DRIFT_KEYS = ("t_rel_pct", "r_rel_deg_per_100m", "drift_m_per_m", "max_jump_m")


class ArtifactError(BenchError):
    """Stored artifacts are unreadable or inconsistent; the message names the file."""


@dataclass
class Artifacts:
    """One VIO problem's stored filter results (see the module doc for each field)."""

    folder: Path
    manifest: dict
    calibrations: pd.DataFrame
    drives: dict[str, pd.DataFrame]
    trajectories: dict[str, dict[str, np.ndarray]]
    profile: pd.DataFrame | None


def _runs(records: list[dict]) -> list[dict]:
    """The finished runs in a fixed order (optimizer, seed, job folder)."""
    return sorted(records, key=lambda r: (r["optimizer"], int(r["seed"]), str(r.get("job_dir", ""))))


def artifact_key(problem_config: dict, records: list[dict], profile_points: int) -> str:
    """Hex SHA-256 of what the artifacts depend on: schema, problem config, runs' best points."""
    payload = {"schema": SCHEMA, "problem": problem_config, "profile_points": int(profile_points),
               "runs": [(r["optimizer"], int(r["seed"]), [float(v) for v in r["best_x"]]) for r in _runs(records)]}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def folder_name(problem_config: dict) -> str:
    digest = hashlib.sha256(json.dumps(problem_config, sort_keys=True).encode()).hexdigest()[:10]
    return f"{problem_config.get('name', 'problem')}-{digest}"


def median_run_index(values: np.ndarray, seeds: np.ndarray) -> int:
    """Index of the run whose value is the median: sorted by (value, seed), the lower middle one
    for an even count — a typical outcome, not the luckiest, and one real run (not a blend)."""
    order = np.lexsort((np.asarray(seeds), np.asarray(values, float)))
    return int(order[(len(order) - 1) // 2])


def objective_profile(problem, n_points: int = 21, log: Callable[[str], None] | None = None) -> pd.DataFrame:
    """The objective along each variable across its bounds, the others at the truth (or the
    reference when the truth is unknown), in one batch of about ``n_points * d`` filter runs.

    Evaluated through the problem's calibration API (decode, run the filter, position RMSE
    with the problem's divergence penalty), not through ``evaluate``: a truth outside the
    bounds is a valid anchor and is profiled, and flagged (``anchor_in_bounds``).
    Columns: variable, unit, value, offset (value minus the anchor), f (m), anchor_in_bounds,
    in_bounds (this grid point inside the bounds).
    """
    from avio.metrics import position_rmse_objective

    space = problem.space
    anchor = problem.truth if problem.truth is not None else space.reference
    rows, labels = [], []
    for i, name in enumerate(space.names):
        grid = np.unique(np.r_[np.linspace(space.lower[i], space.upper[i], n_points), anchor[i]])
        X = np.tile(anchor, (len(grid), 1))
        X[:, i] = grid
        rows.append(X)
        inside = bool(space.lower[i] <= anchor[i] <= space.upper[i])
        labels += [(name, space.units[i], v, v - anchor[i], inside, bool(space.lower[i] <= v <= space.upper[i]))
                   for v in grid]
    f = []
    started = last = time.perf_counter()
    for name, X in zip(space.names, rows):  # one batch per variable (the filter is as fast at any batch size)
        cal = problem.calibration_space.decode(X)
        if hasattr(problem, "score"):  # the problem's own objective over its calibration drives
            f.append(np.asarray(problem.score(cal)[0], float))
        else:
            result = problem.run_filter(cal, problem.sequence)
            f.append(position_rmse_objective(result, problem.sequence.truth, problem.divergence_penalty_m))
        if log and time.perf_counter() - last >= 5.0:  # a line every 5 s or so, not one per variable
            last = time.perf_counter()
            log(f"    profile: up to {name} done ({last - started:.1f} s so far)")
    f = np.concatenate(f)
    frame = pd.DataFrame(labels, columns=["variable", "unit", "value", "offset", "anchor_in_bounds", "in_bounds"])
    frame.insert(4, "f", f)
    return frame


def space_info(problem) -> dict:
    """The problem's space as plain data: kind, names, units, bounds, reference, truth (or
    None) and, per variable, whether the truth lies inside the bounds."""
    space = problem.space
    truth = None if problem.truth is None else [float(v) for v in problem.truth]
    return {"kind": getattr(getattr(problem, "calibration_space", None), "kind", None),
            "names": list(space.names), "units": list(space.units),
            "lower": [float(v) for v in space.lower], "upper": [float(v) for v in space.upper],
            "reference": [float(v) for v in space.reference], "truth": truth,
            "truth_in_bounds": None if truth is None else
            [bool(lo <= t <= hi) for t, lo, hi in zip(truth, space.lower, space.upper)]}


def _sources(problem, records: list[dict]):
    """(rows, calibrations): one row per source, and the batch of their calibrations."""
    from avio.calibration import Calibration

    rows = [{"source": "reference", "optimizer": "", "seed": -1, "best_f": problem.f_reference}]
    cals = [problem.sequence.reference_calibration]
    truth = problem.sequence.truth_calibration
    if truth is not None:
        rows.append({"source": "truth", "optimizer": "", "seed": -1,
                     "best_f": np.nan if problem.f_truth is None else problem.f_truth})
        cals.append(truth)
    runs = _runs(records)
    if runs:
        cals.append(problem.calibration_space.decode(np.array([r["best_x"] for r in runs], float)))
        rows += [{"source": "run", "optimizer": r["optimizer"], "seed": int(r["seed"]), "best_f": float(r["best_f"])}
                 for r in runs]
    return rows, Calibration.stack(cals)


def compute(problem, problem_config: dict, records: list[dict], folder: Path, profile_points: int,
            log: Callable[[str], None] = print) -> Artifacts:
    """Run the filter for everything the tables and figures need and write it into ``folder``."""
    space = problem.space
    table, batch = _calibration_table(problem, records)
    drives, trajectories, meta = {}, {}, {}
    for which, sequence in (("calibration", problem.sequence), ("holdout", problem.holdout)):
        if sequence is None:
            continue
        drives[which], trajectories[which], meta[which] = _run_drive(problem, which, sequence, table, batch, log)
    profile = None
    if profile_points > 0:
        started = time.perf_counter()
        log(f"  profiling the objective: {profile_points} points along each of {space.dim} variables")
        profile = objective_profile(problem, profile_points, log)
        log(f"  profile done in {time.perf_counter() - started:.1f} s")
    manifest = {
        "schema": SCHEMA, "key": artifact_key(problem_config, records, profile_points),
        "problem": problem.name, "problem_config": problem_config, "space": space_info(problem),
        "f_reference": problem.f_reference, "f_truth": problem.f_truth,
        "objective": getattr(problem, "objective", "position_rmse"),
        "drives": meta,
    }
    art = Artifacts(Path(folder), manifest, table, drives, trajectories, profile)
    try:
        _write(art)
    except OSError as err:  # a read-only sweep folder: the report still builds, from memory
        log(f"  note: could not store artifacts in {folder} ({err.strerror}); they will be recomputed next time")
    return art


def _calibration_table(problem, records: list[dict]):
    """(table, calibrations): one row per source with its point, paper variables and errors; their batch."""
    from avio.calibration import calibration_errors
    from bench.problems.calibration_space import paper_parameters

    space = problem.space
    rows, batch = _sources(problem, records)
    table = pd.DataFrame(rows)
    for i, name in enumerate(space.names):
        table[f"x.{name}"] = problem.calibration_space.encode(batch)[:, i]
    from avio.reference import PAPER_TABLE1

    paper = paper_parameters(batch, problem.sequence.reference_calibration)
    for i, name in enumerate(PAPER_TABLE1):
        table[f"paper.{name}"] = paper[:, i]
    truth_cal = problem.sequence.truth_calibration
    if truth_cal is not None:
        for key, values in calibration_errors(batch, truth_cal).items():
            if key == "time_offset_error_ms" and "td" not in space.names:
                continue
            table[f"err.{key}"] = values
    return table, batch


def _run_drive(problem, which: str, sequence, table: pd.DataFrame, batch,
               log: Callable[[str], None]) -> tuple[pd.DataFrame, dict, dict]:
    """The VIO on one drive at the table's calibrations: (its error rows, trajectories, drive meta)."""
    from avio.calibration import Calibration
    from avio.metrics import drift_metrics, pose_errors

    truth_cal = problem.sequence.truth_calibration
    runs = table["source"] == "run"
    # the drive's own reference and truth; the runs' calibrations are the same on every drive
    drive_batch = Calibration.stack([sequence.reference_calibration]
                                    + ([sequence.truth_calibration] if truth_cal is not None else [])
                                    + ([batch[int(np.argmax(runs.to_numpy())):]] if runs.any() else []))
    started = time.perf_counter()
    log(f"  running the VIO on the {which} drive {sequence.name} ({sequence.n_frames} frames, "
        f"{sequence.path_length_m():.0f} m) for {len(drive_batch)} calibrations")
    result = problem.run_filter(drive_batch, sequence)
    errors = pose_errors(result, sequence.truth)
    drift = drift_metrics(result.p_world_imu_m, result.R_world_imu, sequence.truth)
    frame = table[["source", "optimizer", "seed", "best_f"]].copy()
    for state in STATES:
        for stat in ("rmse", "mean", "std"):
            frame[f"{state}_{stat}"] = errors[f"{state}_{stat}"]
    for key in DRIFT_KEYS:
        frame[key] = drift[key]
    frame["diverged"] = result.diverged.astype(int)
    # trajectories of the reference, the truth and each optimiser's median run (by best f)
    keep = list(np.flatnonzero(~runs.to_numpy()))
    labels = [str(s) for s in table.loc[keep, "source"]]
    for optimizer, group in table[runs].groupby("optimizer", sort=True):
        k = group.index[median_run_index(group["best_f"].to_numpy(), group["seed"].to_numpy())]
        keep.append(int(k))
        labels.append(f"AVIO {optimizer} (seed {int(table.loc[k, 'seed'])})")
    trajectories = {
        "labels": np.array(labels), "t_s": sequence.frame_t_s - sequence.frame_t_s[0],
        "p_true": sequence.truth.p_world_imu_m, "p_est": result.p_world_imu_m[keep],
        **{f"e_{state}": errors[f"{state}_errors"][keep] for state in STATES}}
    meta = {"name": sequence.name, "n_frames": int(sequence.n_frames),
            "path_length_m": float(sequence.path_length_m()),
            "seconds": round(time.perf_counter() - started, 1)}
    return frame, trajectories, meta


def _write(art: Artifacts) -> None:
    folder = art.folder
    folder.mkdir(parents=True, exist_ok=True)
    art.calibrations.to_csv(folder / "calibrations.csv", index=False, lineterminator="\n")
    for which, frame in art.drives.items():
        frame.to_csv(folder / f"drive_{which}.csv", index=False, lineterminator="\n")
        np.savez_compressed(folder / f"trajectories_{which}.npz", **art.trajectories[which])
    if art.profile is not None:
        art.profile.to_csv(folder / "profile.csv", index=False, lineterminator="\n")
    # the manifest last, atomically: a set without one (an interrupted write) is recomputed
    tmp = folder / ".manifest.json.tmp"
    tmp.write_text(json.dumps(art.manifest, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, folder / "manifest.json")


def load(folder: Path) -> Artifacts:
    """Read a stored set; ArtifactError naming the file when one is missing or unreadable."""
    folder = Path(folder)
    path = folder / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
        path = folder / "calibrations.csv"
        calibrations = pd.read_csv(path, keep_default_na=False, na_values=[""],
                                   dtype={"source": str, "optimizer": str})
        calibrations["optimizer"] = calibrations["optimizer"].fillna("")
        drives, trajectories = {}, {}
        for which in manifest["drives"]:
            path = folder / f"drive_{which}.csv"
            drives[which] = pd.read_csv(path, dtype={"source": str, "optimizer": str})
            drives[which]["optimizer"] = drives[which]["optimizer"].fillna("")
            path = folder / f"trajectories_{which}.npz"
            with np.load(path, allow_pickle=False) as data:
                trajectories[which] = {k: data[k] for k in data.files}
        path = folder / "profile.csv"
        profile = pd.read_csv(path) if path.exists() else None
    except FileNotFoundError:
        raise ArtifactError(f"{path}: missing (delete {folder} or pass --recompute)") from None
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as err:
        raise ArtifactError(f"{path}: unreadable artifact ({type(err).__name__}: {err}); "
                            f"delete {folder} or pass --recompute") from None
    return Artifacts(folder, manifest, calibrations, drives, trajectories, profile)


def stored_key(folder: Path) -> str | None:
    """The key of the set stored in ``folder``, or None when there is none (or it is unreadable)."""
    try:
        return json.loads((Path(folder) / "manifest.json").read_text()).get("key")
    except (OSError, ValueError, AttributeError):
        return None


def load_or_compute(problem_config: dict, records: list[dict], store: Path, *, profile_points: int = 21,
                    recompute: bool = False, log: Callable[[str], None] = print) -> Artifacts:
    """The artifacts of one VIO problem's finished runs: loaded from ``store`` when their key
    matches, else computed (building the problem from its config, running the filter) and stored."""
    folder = Path(store) / folder_name(problem_config)
    key = artifact_key(problem_config, records, profile_points)
    have = stored_key(folder)
    if have == key and not recompute:
        return load(folder)
    why = "asked to recompute" if recompute else ("records changed since they were stored" if have
                                                   else "first report of these records")
    log(f"computing the filter artifacts of {problem_config.get('name')} ({why}) into {folder}")
    started = time.perf_counter()
    log("  building the problem (simulating or loading its drives; compiling the VIO filter on a first run, ~30 s)")
    from avio.errors import AvioError
    from bench.problems.base import build_problem

    try:
        problem = build_problem({"problem": problem_config})
    except (BenchError, AvioError, TypeError, OSError) as err:  # ProblemError, SpaceError, a DatasetError
        raise ArtifactError(f"cannot rebuild problem {problem_config.get('name')!r} from the records' config "
                            f"({type(err).__name__}: {err})") from None
    log(f"  problem built in {time.perf_counter() - started:.1f} s")
    try:
        art = compute(problem, problem_config, records, folder, profile_points, log)
    except (BenchError, AvioError) as err:  # ProblemError, FilterError, MetricsError, SequenceError: said, not hidden
        raise ArtifactError(f"running the VIO for the tables of {problem_config.get('name')!r} failed "
                            f"({type(err).__name__}: {err})") from None
    log(f"  artifacts done in {time.perf_counter() - started:.1f} s")
    return art
