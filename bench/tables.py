"""The paper's Tables 1–3 rebuilt from run records of a VIO problem, with the paper's values beside.

    python -m bench.tables RUNS_DIR... --out results/synthetic

- Table 1: the calibration variables in the paper's parameterisation: reference, bounds,
  truth (when known), the paper's PSO–GA, and each optimiser's calibrated values (median and
  IQR over seeds); a second table gives the calibration errors against the truth.
- Tables 2 and 3: position (m), velocity (m/s) and attitude (deg) error RMSE, mean and std of
  the VIO with the reference calibration and with each optimiser's calibration (AVIO, the
  median over seeds), on the calibration drive and on the held-out drive.

The problem is rebuilt from the records' own config, so the tables depend on nothing else.
Written as CSV, Markdown and LaTeX.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from avio.metrics import pose_errors
from avio.reference import PAPER_TABLE1
from avio.sequence import Calibration
from bench.calibration_space import paper_parameters
from bench import problems
from bench.job import build_problem
from bench.problems.vio import VioRmseProblem, calibration_errors
from bench.records import RecordError, find_job_dirs, read_record

PAPER_TABLE23 = {  # (drive, state) -> {method: (rmse, mean, std)}
    ("540m", "position"): {"VIO reference": (4.8944, 2.3549, 1.1641), "AVIO": (2.0736, 1.7936, 0.8551)},
    ("540m", "velocity"): {"VIO reference": (0.5281, 0.4598, 0.1705), "AVIO": (0.1513, 0.1472, 0.1368)},
    ("540m", "attitude"): {"VIO reference": (2.3558, 0.6493, 1.1323), "AVIO": (1.9108, 0.5101, 1.0023)},
    ("928m", "position"): {"VIO reference": (27.3307, 18.3963, 7.2341), "AVIO": (19.8791, 12.6847, 2.3142)},
    ("928m", "velocity"): {"VIO reference": (1.5723, 0.9824, 0.9876), "AVIO": (1.0134, 0.7925, 0.6541)},
    ("928m", "attitude"): {"VIO reference": (2.2124, 1.2344, 1.9856), "AVIO": (1.3482, 0.9821, 1.4422)},
}
UNITS = {"position": "m", "velocity": "m/s", "attitude": "deg"}


class TablesError(ValueError):
    """The records cannot make the tables (none finished, mixed problems); the message says why."""


def _finished_records(dirs) -> list[dict]:
    records = [r for r in (read_record(d) for d in find_job_dirs(dirs)) if r and r.get("status") == "ok"]
    if not records:
        raise TablesError(f"no finished job under {', '.join(map(str, dirs))}")
    return records


def _is_vio_problem(name: str) -> bool:
    """Whether the registered problem ``name`` is a VIO problem (analytic and unknown ones are not)."""
    try:
        factory = problems.get(name)
    except KeyError:
        return False
    return isinstance(factory, type) and issubclass(factory, VioRmseProblem)


def _problem_key(record: dict) -> str:
    return json.dumps(record["config"]["problem"], sort_keys=True)


def best_calibrations(problem: VioRmseProblem, records: list[dict]) -> dict[str, Calibration]:
    """Per optimiser, the batch of its seeds' best calibrations (ordered by seed)."""
    out = {}
    for name in sorted({r["optimizer"] for r in records}):
        rows = sorted((r for r in records if r["optimizer"] == name), key=lambda r: r["seed"])
        out[name] = problem.calibration_space.decode(np.array([r["best_x"] for r in rows]))
    return out


def _paper_values(problem: VioRmseProblem, cal: Calibration) -> np.ndarray:
    """(n, 10) calibrations in the paper's variables (fx, fy, cx, cy, roll, pitch, yaw, tx, ty, tz)."""
    return paper_parameters(cal, problem.sequence.reference_calibration)


def _iqr(x: np.ndarray, axis=0) -> np.ndarray:
    return np.subtract(*np.nanpercentile(x, [75, 25], axis=axis))


def table1(problem: VioRmseProblem, calibrations: dict[str, Calibration]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(values, errors): rows per source, one column per paper variable; errors per optimiser."""
    names = list(PAPER_TABLE1)
    ref = _paper_values(problem, problem.sequence.reference_calibration)[0]
    rows = {"reference (ours)": ref,
            "lower": [PAPER_TABLE1[n][1] for n in names], "upper": [PAPER_TABLE1[n][2] for n in names]}
    truth = problem.sequence.truth_calibration
    if truth is not None:
        rows["truth"] = _paper_values(problem, truth)[0]
    rows["PSO-GA (paper)"] = [PAPER_TABLE1[n][3] for n in names]
    rows["reference (paper)"] = [PAPER_TABLE1[n][0] for n in names]
    for opt, cal in calibrations.items():
        values = _paper_values(problem, cal)
        rows[f"{opt} median"] = np.median(values, axis=0)
        rows[f"{opt} IQR"] = _iqr(values)
    values = pd.DataFrame(rows, index=names).T
    values.index.name = "source"
    errors = None
    if truth is not None:
        err_rows = {"reference": {k: v[0] for k, v in calibration_errors(problem.sequence.reference_calibration,
                                                                         truth).items()}}
        for opt, cal in calibrations.items():
            errs = calibration_errors(cal, truth)
            err_rows[f"{opt} median"] = {k: float(np.median(v)) for k, v in errs.items()}
            err_rows[f"{opt} IQR"] = {k: float(_iqr(v)) for k, v in errs.items()}
        errors = pd.DataFrame(err_rows).T
        if "td" not in problem.space.names:
            errors = errors.drop(columns="time_offset_error_ms")
        errors.index.name = "source"
    return values, errors


def trajectory_table(problem: VioRmseProblem, calibrations: dict[str, Calibration], which: str,
                     paper_drive: str | None) -> pd.DataFrame:
    """RMSE/mean/std of position, velocity and attitude errors on one drive (calibration or holdout)."""
    sequence = problem.sequence if which == "calibration" else problem.holdout
    batch = Calibration.stack([sequence.reference_calibration] + list(calibrations.values()))
    errors = pose_errors(problem.run_filter(batch, sequence), sequence.truth)
    owners = ["VIO reference"] + [f"AVIO {opt}" for opt, cal in calibrations.items() for _ in range(len(cal))]
    rows = []
    for state in ("position", "velocity", "attitude"):
        for method in dict.fromkeys(owners):
            idx = [i for i, o in enumerate(owners) if o == method]
            row = {"state": f"{state} ({UNITS[state]})", "method": method}
            for stat in ("rmse", "mean", "std"):
                row[stat] = float(np.median(errors[f"{state}_{stat}"][idx]))
            if paper_drive:
                paper = PAPER_TABLE23[(paper_drive, state)]["VIO reference" if method == "VIO reference" else "AVIO"]
                row.update({"paper rmse": paper[0], "paper mean": paper[1], "paper std": paper[2]})
            rows.append(row)
    return pd.DataFrame(rows)


def _write(frame: pd.DataFrame, out: Path, stem: str, caption: str, index: bool) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}.csv", out / f"{stem}.md", out / f"{stem}.tex"]
    frame.to_csv(paths[0], index=index, float_format="%.6g")
    paths[1].write_text(f"{caption}\n\n" + frame.to_markdown(index=index, floatfmt=".4g") + "\n")
    paths[2].write_text(frame.style.format(precision=4).to_latex(caption=caption, hrules=True) if index else
                        frame.style.hide(axis="index").format(precision=4).to_latex(caption=caption, hrules=True))
    return paths


def build_tables(dirs, out: Path, figures: bool = True, profile_points: int = 21) -> list[Path]:
    """Write Tables 1–3 (and, with ``figures``, the paper's figures and the objective profile) for
    every VIO problem found under ``dirs`` into ``out`` (a subfolder per problem when there are
    several). Returns the files written."""
    records = _finished_records(dirs)
    groups = {}
    for r in records:
        if not _is_vio_problem(r["problem"]):
            continue
        groups.setdefault(_problem_key(r), []).append(r)
    if not groups:
        raise TablesError("no VIO problem among the finished jobs (Tables 1-3 need a VIO problem)")
    written = []
    for key, group in sorted(groups.items()):
        problem = build_problem(group[0]["config"])
        folder = Path(out) if len(groups) == 1 else Path(out) / group[0]["problem"]
        cals = best_calibrations(problem, group)
        values, errors = table1(problem, cals)
        written += _write(values, folder, "table1", f"Table 1 ({problem.name}): calibration values", True)
        if errors is not None:
            written += _write(errors, folder, "table1_errors",
                              f"Table 1b ({problem.name}): calibration errors against the truth", True)
        written += _write(trajectory_table(problem, cals, "calibration", "540m"), folder, "table2",
                          f"Table 2 ({problem.name}): errors on the calibration drive "
                          f"({problem.sequence.name}, {problem.sequence.path_length_m():.0f} m)", False)
        if problem.holdout is not None:
            written += _write(trajectory_table(problem, cals, "holdout", "928m"), folder, "table3",
                              f"Table 3 ({problem.name}): errors on the held-out drive "
                              f"({problem.holdout.name}, {problem.holdout.path_length_m():.0f} m)", False)
        if figures:
            written += _figures(problem, group, folder / "figures", profile_points)
    return written


def leading_optimizer(records: list[dict]) -> str:
    """The optimiser with the lowest median best f (ties: by name)."""
    frame = pd.DataFrame([(r["optimizer"], r["best_f"]) for r in records], columns=["optimizer", "best_f"])
    medians = frame.groupby("optimizer")["best_f"].median()
    return sorted(medians.items(), key=lambda kv: (kv[1], kv[0]))[0][0]


def _figures(problem: VioRmseProblem, records: list[dict], out: Path, profile_points: int) -> list[Path]:
    from bench import paper_figures

    written = paper_figures.convergence_figures(problem, records, out)
    leader = leading_optimizer(records)
    avio = paper_figures.median_seed_calibration(problem, records, leader)
    written += paper_figures.trajectory_figures(problem, avio, leader, out)
    profile = paper_figures.objective_profile(problem, profile_points)
    profile.to_csv(out / "profile.csv", index=False, float_format="%.6g")
    anchor = "truth" if problem.truth is not None else "reference"
    written += [out / "profile.csv", paper_figures.profile_figure(profile, out / "profile.png", anchor)]
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tables", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="sweep or job folders")
    parser.add_argument("--out", type=Path, required=True, help="folder for the tables")
    parser.add_argument("--no-figures", action="store_true", help="tables only")
    parser.add_argument("--profile-points", type=int, default=21, help="grid points per variable")
    args = parser.parse_args(argv)
    try:
        for path in build_tables(args.dirs, args.out, not args.no_figures, args.profile_points):
            print(path)
    except (TablesError, RecordError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
