"""The paper's Tables 1–3 rebuilt from run records of a VIO problem, with the paper's values beside.

    python -m bench.report.paper RUNS_DIR... --out results/synthetic [--recompute]

- Table 1: the calibration variables in the paper's parameterisation: reference, the paper's
  Table 1 bounds, truth (when known), the paper's PSO–GA, and each optimiser's calibrated
  values (median and IQR over seeds); Table 1b gives the calibration errors against the truth.
- Tables 2 and 3: position (m), velocity (m/s) and attitude (deg) error RMSE, mean and std, and
  drift (KITTI's t_rel in %, r_rel in deg/100 m, per-metre drift, the largest one-frame jump;
  ``avio.metrics.drift_metrics``) of the VIO with the reference calibration, with the truth,
  and with each optimiser's calibration, on the calibration drive and on the held-out drive.
  **Median row**: per optimiser and state, the run (seed) whose RMSE of that state is the
  median over its seeds (the lower middle one for an even count); the row gives that run's
  RMSE, mean, std and drift together, and its seed — never medians taken column by column.
  The paper's values (``bench.paper``) stand beside ours only on the drives that reproduce the
  paper's, labelled with what is real and what is simulated.

Everything needing the filter comes from ``bench.report.paper.artifacts`` (computed once per sweep and
stored in ``<sweep>/artifacts/``), so the tables rebuild from records in well under a second;
the problem is rebuilt from the records' own config only when the artifacts are computed.
Written as CSV, Markdown and LaTeX.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from avio.errors import AvioError
from avio.reference import PAPER_TABLE1
from bench import problems
from bench.errors import BenchError
from bench.records import find_job_dirs, read_record
from bench.report.paper.artifacts import DRIFT_KEYS, STATES, ArtifactError, Artifacts, load_or_compute, median_run_index
from bench.report.paper.values import PAPER_DATA, PAPER_TABLE23, data_label, paper_drive, table1_applies

UNITS = {"position": "m", "velocity": "m/s", "attitude": "deg"}
__all__ = ["PAPER_TABLE23", "TablesError", "build_tables", "table1", "trajectory_table"]


class TablesError(BenchError):
    """The records cannot make the tables (none finished, mixed problems); the message says why."""


def _finished_records(dirs) -> list[dict]:
    records = [r for r in (read_record(d) for d in find_job_dirs(dirs)) if r and r.get("status") == "ok"
               and r.get("best_x") is not None]
    if not records:
        raise TablesError(f"no finished job under {', '.join(map(str, dirs))}")
    return records


def _is_vio_problem(name: str) -> bool:
    """Whether the registered problem ``name`` is a VIO problem (analytic and unknown ones are not)."""
    from bench.problems.vio import VioProblem

    try:
        factory = problems.get(name)
    except KeyError:
        return False
    return isinstance(factory, type) and issubclass(factory, VioProblem)


def _problem_key(record: dict) -> str:
    return json.dumps(record["config"]["problem"], sort_keys=True)


def _instance_of(record: dict) -> int:
    value = record.get("instance", (record.get("config") or {}).get("instance"))
    return int(value) if value is not None else int(((record["config"]["problem"].get("params") or {})
                                                     .get("data_seed") or 0))


def _first_instances(groups: dict[str, list[dict]]) -> dict[str, list[dict]]:
    """One group per problem setting: the paper's tables reproduce one camera and drive, so a sweep
    over instances (each its own data, Tables 1-3 costing a VIO run per optimiser) gets them for its
    first instance only; the verdicts use every instance."""
    first: dict[str, tuple[int, str]] = {}
    for key, group in groups.items():
        params = dict(group[0]["config"]["problem"].get("params") or {})
        params.pop("data_seed", None)
        setting = json.dumps({**group[0]["config"]["problem"], "params": params}, sort_keys=True, default=str)
        candidate = (min(map(_instance_of, group)), key)
        first[setting] = min(first.get(setting, candidate), candidate)
    return {key: groups[key] for _, key in first.values()}


def _iqr(x: np.ndarray, axis=0) -> np.ndarray:
    return np.subtract(*np.nanpercentile(x, [75, 25], axis=axis))


def table1(art: Artifacts) -> tuple[pd.DataFrame, pd.DataFrame | None]:
    """(values, errors): rows per source, one column per paper variable; errors per optimiser."""
    names = list(PAPER_TABLE1)
    cal = art.calibrations
    paper_cols = [f"paper.{n}" for n in names]
    def source(s):
        return cal[cal["source"] == s]
    paper = table1_applies(art.manifest["problem"])
    rows = {"reference (ours)": source("reference")[paper_cols].to_numpy()[0]}
    if paper:
        rows["lower (paper Table 1)"] = [PAPER_TABLE1[n][1] for n in names]
        rows["upper (paper Table 1)"] = [PAPER_TABLE1[n][2] for n in names]
    if len(source("truth")):
        # EuRoC's "truth" is Kalibr's target-based calibration, the trusted reference of that rig
        label = "Kalibr (trusted reference)" if art.manifest["problem"] == "euroc" else "truth"
        rows[label] = source("truth")[paper_cols].to_numpy()[0]
    if paper:
        rows["PSO-GA (paper, real KITTI)"] = [PAPER_TABLE1[n][3] for n in names]
        rows["reference (paper)"] = [PAPER_TABLE1[n][0] for n in names]
    runs = cal[cal["source"] == "run"]
    for opt, group in runs.groupby("optimizer", sort=True):
        values = group[paper_cols].to_numpy()
        rows[f"{opt} median"] = np.median(values, axis=0)
        rows[f"{opt} IQR"] = _iqr(values)
    values = pd.DataFrame(rows, index=names).T
    values.index.name = "source"
    err_cols = [c for c in cal.columns if c.startswith("err.")]
    if not err_cols:
        return values, None
    err_rows = {"reference": source("reference")[err_cols].iloc[0]}
    for opt, group in runs.groupby("optimizer", sort=True):
        err_rows[f"{opt} median"] = group[err_cols].median()
        err_rows[f"{opt} IQR"] = pd.Series(_iqr(group[err_cols].to_numpy()), index=err_cols)
    errors = pd.DataFrame(err_rows).T.rename(columns=lambda c: c[len("err."):])
    errors.index.name = "source"
    return values, errors


def trajectory_table(art: Artifacts, which: str, paper: str | None) -> pd.DataFrame:
    """Position, velocity and attitude error RMSE/mean/std and drift on one drive; one row per
    (state, method); an optimiser's row is its median run for that state (module doc)."""
    drive = art.drives[which]
    rows = []
    for state in STATES:
        stats = [f"{state}_{s}" for s in ("rmse", "mean", "std")]
        methods = [("VIO reference", drive[drive["source"] == "reference"].iloc[0]),
                   *([("VIO truth calibration", drive[drive["source"] == "truth"].iloc[0])]
                     if (drive["source"] == "truth").any() else [])]
        runs = drive[drive["source"] == "run"]
        for opt, group in runs.groupby("optimizer", sort=True):
            k = median_run_index(group[stats[0]].to_numpy(), group["seed"].to_numpy())
            methods.append((f"AVIO {opt}", group.iloc[k]))
        for method, run in methods:
            row = {"state": f"{state} ({UNITS[state]})", "method": method,
                   "seed": int(run["seed"]) if run["source"] == "run" else np.nan,
                   "rmse": run[stats[0]], "mean": run[stats[1]], "std": run[stats[2]],
                   **{key: run[key] for key in DRIFT_KEYS}}
            if paper:
                ref = PAPER_TABLE23[(paper, state)]
                values = ref["VIO reference"] if method == "VIO reference" else (
                    ref["AVIO"] if method.startswith("AVIO") else (np.nan,) * 3)
                row.update({"paper rmse": values[0], "paper mean": values[1], "paper std": values[2]})
            rows.append(row)
    return pd.DataFrame(rows)


def _write(frame: pd.DataFrame, out: Path, stem: str, caption: str, index: bool) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}.csv", out / f"{stem}.md", out / f"{stem}.tex"]
    frame.to_csv(paths[0], index=index, float_format="%.6g", lineterminator="\n")
    paths[1].write_text(f"{caption}\n\n" + frame.to_markdown(index=index, floatfmt=".4g") + "\n")
    style = frame.style if index else frame.style.hide(axis="index")
    paths[2].write_text(style.format(precision=4, na_rep="--").to_latex(caption=caption.replace("%", r"\%"),
                                                                        hrules=True))
    return paths


def _outside_note(art: Artifacts) -> str:
    space = art.manifest["space"]
    if space.get("truth") is None:
        return ""
    outside = [n for n, inside in zip(space["names"], space["truth_in_bounds"]) if not inside]
    return f" The truth lies OUTSIDE the search bounds for: {', '.join(outside)}." if outside else ""


def _frozen_note(problem_config: dict) -> str:
    """Which variables the optimisers did not calibrate (``fixed``, ``tie_focal``)."""
    params = problem_config.get("params") or {}
    parts = []
    if params.get("fixed"):
        parts.append(f"frozen at the reference, not calibrated: {', '.join(params['fixed'])}")
    if params.get("tie_focal"):
        parts.append("fy tied to fx (not a variable)")
    return f" Variables {'; '.join(parts)}." if parts else ""


def _drive_caption(art: Artifacts, table: str, which: str, paper: str | None) -> str:
    drive = art.manifest["drives"][which]
    label = "calibration drive" if which == "calibration" else "held-out drive"
    data = data_label(art.manifest["problem"])
    beside = (f" Beside: the paper's Table {table[-1]} ({PAPER_DATA}, ~{paper[:-1]} m)." if paper
              else " The paper has no values for this drive.")
    return (f"Table {table[-1]} ({art.manifest['problem']}): errors on the {label} ({drive['name']}, "
            f"{drive['path_length_m']:.0f} m) — {data}.{beside} Optimiser rows: per state, the seed whose "
            f"RMSE is the median over seeds, with that run's mean, std and drift. "
            f"Drift: t_rel (%) and r_rel (deg/100 m) over 100–800 m segments (KITTI), drift_m_per_m per metre, "
            f"max_jump_m the largest one-frame position jump error.")


def leading_optimizer(records: list[dict]) -> str:
    """The optimiser with the lowest median best f (ties: by name)."""
    frame = pd.DataFrame([(r["optimizer"], r["best_f"]) for r in records], columns=["optimizer", "best_f"])
    medians = frame.groupby("optimizer")["best_f"].median()
    return sorted(medians.items(), key=lambda kv: (kv[1], kv[0]))[0][0]


def _figures(art: Artifacts, records: list[dict], out: Path, log) -> list[Path]:
    from bench.report.paper import figures as paper_figures

    space = art.manifest["space"]
    written = paper_figures.convergence_figures(space, records, out, log)
    written += paper_figures.trajectory_figures(art, leading_optimizer(records), out)
    if art.profile is not None:
        art.profile.to_csv(out / "profile.csv", index=False, float_format="%.6g", lineterminator="\n")
        written += [out / "profile.csv", paper_figures.profile_figure(
            art.profile, space, out / "profile.png", art.manifest.get("objective", "position_rmse"))]
    return written


def default_store(dirs) -> Path:
    """Where artifacts are kept: ``artifacts/`` in the first folder given (the sweep folder)."""
    first = Path(dirs[0])
    return (first if first.is_dir() else first.parent) / "artifacts"


def build_tables(dirs, out: Path, figures: bool = True, profile_points: int = 21, *, store: Path | None = None,
                 recompute: bool = False, log: Callable[[str], None] = print) -> list[Path]:
    """Write Tables 1–3 (and, with ``figures``, the paper's figures and the objective profile) for
    every VIO problem found under ``dirs`` into ``out`` (a subfolder per problem when there are
    several). Filter results come from ``store`` (default ``default_store(dirs)``), computed
    there first when missing or stale (``bench.report.paper.artifacts``). Returns the files written."""
    records = _finished_records(dirs)
    groups = {}
    for r in records:
        if not _is_vio_problem(r["problem"]):
            continue
        groups.setdefault(_problem_key(r), []).append(r)
    if not groups:
        raise TablesError("no VIO problem among the finished jobs (Tables 1-3 need a VIO problem)")
    groups = _first_instances(groups)
    store = Path(store) if store is not None else default_store(dirs)
    written = []
    for key, group in sorted(groups.items()):
        config = group[0]["config"]["problem"]
        try:
            art = load_or_compute(config, group, store, profile_points=profile_points,
                                  recompute=recompute, log=log)
        except ArtifactError as err:
            raise TablesError(str(err)) from None
        name = art.manifest["problem"]
        folder = Path(out) if len(groups) == 1 else Path(out) / group[0]["problem"]
        values, errors = table1(art)
        beside = ("PSO-GA, reference and bounds (paper): the paper's Table 1, real KITTI" if table1_applies(name)
                  else "the paper's Table 1 is for another camera and is not shown")
        written += _write(values, folder, "table1", f"Table 1 ({name}): calibration values in the paper's "
                          f"variables ({data_label(name)}; {beside})." + _frozen_note(config) + _outside_note(art),
                          True)
        if errors is not None:
            written += _write(errors, folder, "table1_errors",
                              f"Table 1b ({name}): calibration errors against the truth." + _frozen_note(config)
                              + _outside_note(art), True)
        for which, table in (("calibration", "table2"), ("holdout", "table3")):
            if which in art.drives:
                paper = paper_drive(config, which)
                written += _write(trajectory_table(art, which, paper), folder, table,
                                  _drive_caption(art, table, which, paper), False)
        if figures:
            log(f"drawing the paper's figures for {name}")
            written += _figures(art, group, folder / "figures", log)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.report.paper", description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="+", type=Path, help="sweep or job folders")
    parser.add_argument("--out", type=Path, required=True, help="folder for the tables")
    parser.add_argument("--no-figures", action="store_true", help="tables only")
    parser.add_argument("--profile-points", type=int, default=21, help="grid points per variable")
    parser.add_argument("--recompute", action="store_true", help="re-run the VIO even if stored artifacts match")
    args = parser.parse_args(argv)
    if args.profile_points < 2:
        print("bench.report.paper: error: --profile-points must be at least 2", file=sys.stderr)
        return 2
    def say(msg):
        return print(msg, file=sys.stderr, flush=True)
    try:
        for path in build_tables(args.dirs, args.out, not args.no_figures, args.profile_points,
                                 recompute=args.recompute, log=say):
            print(path)
    except (BenchError, AvioError) as err:  # TablesError, RecordError, ...; anything else is a bug
        print(f"bench.report.paper: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
