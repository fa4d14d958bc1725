"""Summarise the identifiability study (studies/identifiability/make_identifiability.sh): per configuration
(objective x drives x noise realisations x free variables), the calibrated camera's errors against the truth and the
held-out RMSE at the calibrated and at the reference calibration, medians over the seeds.

    python studies/identifiability/identifiability.py results/identifiability

Also the ray error (avio.calibration.ray_error_deg: the largest angle between the IMU-frame
rays of the same pixels under the calibration and the truth), which a principal-point error and
the rotation that compensates it do not add up in, and the held-out RMSE against the truth's,
paired seed by seed, and whether each run's best f is below f(truth) (the optimiser reached the
objective's level at the truth). Writes ``summary.csv``, ``summary.md`` (the table of
studies/identifiability/README.md), ``summary.png`` and ``runs.csv`` into the folder.

    python studies/identifiability/identifiability.py results/identifiability --compare CONFIG_A CONFIG_B

reads the folder's ``runs.csv`` instead and compares two configurations seed by seed (the seeds
both have): for each error, the ray error and the held-out RMSE, the medians, in how many seeds
A is lower than B, the paired two-sided Wilcoxon signed-rank p (bench.report.stats.compare) and that p
Holm-adjusted over the six quantities (``holm_p``: what a claim about any one of them must pass). The held-out
drive of data seed s is the same camera on an independent ~928 m drive
(bench/problems/synthetic.py); it is evaluated here, once per seed, for every configuration's
calibration and the reference in one batch.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.calibration import (
    Calibration,
    calibration_errors,
    ray_error_deg,
)
from avio.metrics import position_rmse_objective
from bench.archive import ARCHIVE, has_records, job_records, pack, unpack
from bench.problems.synthetic import Synthetic, SyntheticParams
from bench.problems.vio import _plain
from bench.report import stats

ERRORS = ("rotation_error_deg", "focal_error_px", "principal_point_error_px", "translation_error_cm")


def decisions(record: dict) -> str:
    """The outlier decisions a run used: its record says (since the likelihood default changed); older records ran with the
    filter's own unless the configuration set them."""
    said = (record.get("problem_identity") or {}).get("outlier_decisions")
    return said or (record["config"]["problem"]["params"].get("filter") or {}).get("outlier_decisions", "own")


def load(folder: Path) -> pd.DataFrame:
    rows = []
    # job folders i<k> (seed<k> before instances), from the files or the configuration's records.tar.xz
    found = [(config.name, record) for config in sorted(p for p in folder.iterdir() if p.is_dir())
             for _, record in job_records(config, "synthetic/*/*/record.json")]
    for config, record in found:
        if record.get("status") != "ok":
            continue
        params = record["config"]["problem"]["params"]
        rows.append({"config": config, "objective": params["objective"],
                     "drives": len(params["drives"]), "rig": params["drives"][0], "noise_realisations": params.get("noise_realisations", 1),
                     "free": len(record["best_x"]), "seed": record["seed"],
                     "decisions": decisions(record),
                     # where each feature's Jacobian is taken (FilterConfig.jacobian_pixels; issue 33)
                     "jacobian": (params.get("filter") or {}).get("jacobian_pixels", "measured"),
                     # the filter's pixel noise when set apart from the default (FilterConfig.pixel_sigma_px), px
                     "filter_sigma_px": (params.get("filter") or {}).get("pixel_sigma_px"),
                     "data_seed": params["data_seed"], "params": params, "best_x": record["best_x"],
                     "evals": record["n_evals"], "best_f": record["best_f"], "f_truth": record["f_truth"],
                     **{k: record["best_metrics"][k] for k in ERRORS}})
    if not rows:
        raise SystemExit(f"{folder}: no finished records")
    return pd.DataFrame(rows)


def best_calibrations(rows: pd.DataFrame, reference: Calibration, image_size_px) -> Calibration:
    """The best point of each run (rows of :func:`load`), decoded in that run's own space around
    the reference (each configuration frees other variables)."""
    cals = []
    for _, row in rows.iterrows():
        params = SyntheticParams(**{k: _plain(v) for k, v in row["params"].items()})
        space = params.space_for(reference, image_size_px)
        cals.append(space.decode(np.asarray(row["best_x"], float)[None]))
    return Calibration.stack(cals)


#: the run parameters that decide its held-out drive and how it is scored (runs sharing them share one batch)
HELD_OUT_KEYS = ("data_seed", "holdout", "sim", "filter", "divergence_penalty_m")


def held_out(runs: pd.DataFrame) -> pd.DataFrame:
    """Held-out RMSE (m) of each run's best calibration and of the reference, one batch per data
    seed and held-out setting (the run's own held-out preset, simulator and filter settings)."""
    out = []
    keys = runs["params"].map(lambda p: json.dumps([p.get(k) for k in HELD_OUT_KEYS], sort_keys=True))
    for key, group in runs.groupby(keys, sort=False):
        params = {k: _plain(v) for k, v in zip(HELD_OUT_KEYS, json.loads(key)) if v is not None}
        if "holdout" not in params:
            raise SystemExit(f"identifiability: the runs of {sorted(set(group['config']))} have no held-out drive")
        first_drive = group.iloc[0]["params"]["drives"][0]  # the camera is drawn with the first drive
        problem = Synthetic(drives=[first_drive], space="local", **params)
        found = best_calibrations(group, problem.sequence.reference_calibration, problem.sequence.image_size_px)
        batch = Calibration.stack([found, problem.sequence.truth_calibration, problem.sequence.reference_calibration])
        result = problem.run_filter(batch, problem.holdout)
        rmse = position_rmse_objective(result, problem.holdout.truth, problem.divergence_penalty_m)
        ref_errors = calibration_errors(problem.sequence.reference_calibration, problem.sequence.truth_calibration)
        rays = ray_error_deg(batch, problem.sequence.truth_calibration, problem.sequence.image_size_px)
        for i, (index, _) in enumerate(group.iterrows()):
            out.append({"index": index, "holdout_rmse_m": rmse[i], "holdout_rmse_truth_m": rmse[-2],
                        "holdout_rmse_reference_m": rmse[-1], "ray_error_deg": rays[i],
                        "reference_ray_error_deg": rays[-1],
                        **{f"reference_{k}": float(ref_errors[k][0]) for k in ERRORS}})
    return pd.DataFrame(out).set_index("index")


def bounds_in(folder: Path):
    """The configuration's Cramér–Rao bounds: the joint likelihood's (cramer_rao.configuration_bound) from
    the folder's ``information_*.npz`` (studies/objective/information_equality.py --save, one per rig) and,
    under ``"data"`` and ``"triplets"``, the data's (data_bound.configuration_bound: the tracks, and
    independent triplets) from its ``data_bound_*.npz`` (studies/identifiability/data_bound.py --save, all
    features): a function of a run's row (:func:`load`) giving the bounds' dict or None (no file for its
    rig, a free variable a file did not measure, or several noise realisations of one drive: not
    independent drives)."""
    sys.path[:0] = [str(ROOT / "studies" / "identifiability"), str(ROOT / "studies" / "objective")]
    import cramer_rao
    import data_bound

    saved = {"information": {}, "data": {}, "triplets": {}}
    for path in sorted(folder.glob("information_*.npz")):
        data = dict(np.load(path))
        saved["information"][str(data.get("rig", "paper_540m"))] = data  # files saved before --rig: the flat city
    for path in sorted(folder.glob("data_bound_*.npz")):
        data = dict(np.load(path))
        if not int(data["max_features"]):
            saved["triplets" if bool(data["triplets"]) else "data"][str(data["rig"])] = data
    cache = {}

    def bound(row) -> dict | None:
        params = row["params"]
        key = (row["rig"], row["drives"], tuple(params.get("fixed") or ()), bool(params.get("tie_focal")),
               bool(params.get("with_time_offset")))
        if row["noise_realisations"] > 1:
            return None
        if key not in cache:
            model = saved["information"].get(row["rig"])
            out = (cramer_rao.configuration_bound(model, *key[1:]) if model is not None else None) or {}
            for which in ("data", "triplets"):
                data = saved[which].get(row["rig"])
                out[which] = data_bound.configuration_bound(data, *key[1:]) if data is not None else None
            cache[key] = out
        return cache[key]

    return bound


def summarise(runs: pd.DataFrame, bound=lambda row: None) -> pd.DataFrame:
    """One row per configuration: medians over its seeds; with ``bound`` (:func:`bounds_in`) each error's
    Cramér–Rao bound and the efficiency, bound ÷ achieved median (issue 33)."""
    rows = []
    for _, g in runs.groupby("config", sort=False):  # one configuration per folder (which variables are free, too)
        first = g.iloc[0]
        row = {"objective": first.objective, "drives": first.drives, "noise_realisations": first.noise_realisations,
               "free": first.free, "evals": int(g.evals.median()), "seeds": len(g), "decisions": first.decisions,
               "jacobian": first.get("jacobian", "measured"), "filter_sigma_px": first.get("filter_sigma_px"),
               "rig": first.get("rig", "paper_540m")}  # the drive preset (full3d_540m: the excited rig)
        for k in ERRORS + ("ray_error_deg",):
            row[k] = g[k].median()
            row[f"reference_{k}"] = g[f"reference_{k}"].median()
        row["holdout_rmse_m"] = g["holdout_rmse_m"].median()
        row["holdout_rmse_truth_m"] = g["holdout_rmse_truth_m"].median()
        row["holdout_rmse_reference_m"] = g["holdout_rmse_reference_m"].median()
        row["holdout_better_than_reference"] = f"{int((g.holdout_rmse_m < g.holdout_rmse_reference_m).sum())}/{len(g)}"
        # Paired, seed by seed: medians taken separately over the seeds cannot say whether the
        # calibration beats the truth (studies/objective/objective_bias.py tests that on fresh drives).
        row["holdout_minus_truth_m"] = (g.holdout_rmse_m - g.holdout_rmse_truth_m).median()
        row["holdout_better_than_truth"] = f"{int((g.holdout_rmse_m < g.holdout_rmse_truth_m).sum())}/{len(g)}"
        # Whose error is it? A run whose best f is above f(truth) stopped short of the objective's
        # level at the truth: that error is the optimiser's. One below it has not necessarily
        # converged (the likelihood's 4-drive, 7-free runs all end below f(truth) at 400
        # evaluations, and on seeds 0-4 1,600 cut their rotation error from 0.54 to 0.15 deg).
        row["best_below_truth"] = f"{int((g.best_f < g.f_truth).sum())}/{len(g)}"
        bounds = bound(first) or {}
        row["bound_information"] = bounds.get("information")
        for k in ERRORS:
            b = bounds.get(k)
            row[f"bound_{k}"] = b
            row[f"efficiency_{k}"] = b / row[k] if b is not None else None
        for which in ("data", "triplets"):  # the data's bounds: the tracks, independent triplets
            row[f"{which}_bound"] = bounds.get(which) is not None
            for k in ERRORS:
                d = (bounds.get(which) or {}).get(k)
                row[f"{which}_bound_{k}"] = d
                row[f"{which}_efficiency_{k}"] = d / row[k] if d is not None else None
        rows.append(row)
    return ordered(pd.DataFrame(rows))


OBJECTIVE_ORDER = ("position_rmse", "innovation_nll", "innovation_nll_joint", "innovation_nll_adjusted")
#: FilterConfig.jacobian_pixels, in the table's order, and how the table and the figure name each
JACOBIAN_ORDER = ("measured", "corrected", "corrected_jacobian")
JACOBIAN_LABELS = {"corrected": (", Jacobian at corrected pixels", ", corr. J"),
                   "corrected_jacobian": (", Jacobian alone at corrected pixels", ", corr. J alone")}


def ordered(summary: pd.DataFrame) -> pd.DataFrame:
    """Rows by objective (the paper's first), drives, noise realisations, free variables (most
    first), budget, seeds and outlier decisions (the filters' own first): the order of the table and the figure."""
    rank = [OBJECTIVE_ORDER.index(o) if o in OBJECTIVE_ORDER else len(OBJECTIVE_ORDER) for o in summary.objective]
    jacobian = summary.get("jacobian", pd.Series("measured", index=summary.index))
    sigma = summary.get("filter_sigma_px", pd.Series(None, index=summary.index, dtype=float))
    keys = summary.assign(_o=rank, _f=-summary.free, _d=summary.decisions != "own",
                          _j=[JACOBIAN_ORDER.index(j) if j in JACOBIAN_ORDER else len(JACOBIAN_ORDER) for j in jacobian],
                          _s=pd.to_numeric(sigma).fillna(0.0))  # the default pixel noise first
    keys = keys.sort_values(["_o", "drives", "noise_realisations", "_f", "evals", "seeds", "_d", "_j", "_s"],
                            kind="stable")
    return summary.loc[keys.index].reset_index(drop=True)


def markdown(summary: pd.DataFrame) -> str:
    """The summary (:func:`summarise`, in its order) as the Markdown table of studies/identifiability/README.md."""
    lines = ["| objective | drives | free | evaluations | seeds | rotation (deg) | focal (px) | principal point (px) | "
             "lever arm (cm) | ray error (deg) | held-out RMSE (m) | held-out − truth, paired (m) | held-out better "
             "than reference / than truth | best f below f(truth) | efficiency: rotation / focal / principal point / "
             "lever arm | against the data's bound: tracks | independent triplets |", "|" + "---|" * 17]
    for r in summary.itertuples():
        drives = f"{r.drives} × {r.noise_realisations} noise" if r.noise_realisations > 1 else f"{r.drives}"
        rig = getattr(r, "rig", "paper_540m")
        drives += f" {rig}" if rig != "paper_540m" else ""
        objective = r.objective + (f" ({r.decisions} decisions)" if r.decisions != "own" else "")
        objective += JACOBIAN_LABELS.get(getattr(r, "jacobian", "measured"), ("", ""))[0] + _sigma_label(r)
        lines.append(f"| {objective} | {drives} | {r.free} | {r.evals} | {r.seeds} | {r.rotation_error_deg:.2f} | "
                     f"{r.focal_error_px:.1f} | {r.principal_point_error_px:.1f} | {r.translation_error_cm:.1f} | "
                     f"{r.ray_error_deg:.2f} | {r.holdout_rmse_m:.2f} | {r.holdout_minus_truth_m:+.2f} | "
                     f"{r.holdout_better_than_reference} / {r.holdout_better_than_truth} | {r.best_below_truth} | "
                     f"{_efficiencies(r)} | {_efficiencies(r, 'data')} | {_efficiencies(r, 'triplets')} |")
    return "\n".join(lines) + "\n"


def _sigma_label(r) -> str:
    """', filter σ 1.0 px' for a row whose filter assumes another pixel noise than the default."""
    sigma = getattr(r, "filter_sigma_px", None)
    return "" if sigma is None or pd.isna(sigma) else f", filter σ {float(sigma):g} px"


def _efficiencies(r, which: str = "") -> str:
    """The row's efficiencies, bound ÷ achieved (``which``: "" the joint likelihood's bound, "data" or
    "triplets" the data's): '—' for an error whose variables are not all free, blank without a bound
    (OPG: the bound from the scores' outer product)."""
    has = bool(getattr(r, f"{which}_bound", False)) if which else isinstance(getattr(r, "bound_information", None), str)
    if not has:
        return ""
    vals = [getattr(r, f"{which}_efficiency_{k}" if which else f"efficiency_{k}") for k in ERRORS]
    text = " / ".join("—" if v is None or pd.isna(v) else f"{v:.2f}" for v in vals)
    return text + (" (OPG)" if not which and r.bound_information == "opg" else "")


def figure(summary: pd.DataFrame, path: Path) -> None:
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    colours = {"position_rmse": "tab:blue", "innovation_nll": "tab:orange"}
    # one short line per bar: drives (x noise realisations), free variables; colour: objective
    budgets = summary.evals.nunique() > 1  # the budget (and seed count) in the label only where the study varies it
    usual = summary.seeds.mode().iloc[0]
    labels = [f"{r.drives}{f'x{r.noise_realisations}n' if r.noise_realisations > 1 else ''} dr, {r.free} free"
              + (f", {r.evals} ev" if budgets else "") + (f", {r.seeds} seeds" if r.seeds != usual else "")
              + (f", {r.decisions} dec" if r.decisions != "own" else "")
              + JACOBIAN_LABELS.get(getattr(r, "jacobian", "measured"), ("", ""))[1] + _sigma_label(r).replace("filter ", "")
              for r in summary.itertuples()]
    fig = Figure(figsize=(15, 4.2))
    titles = ("rotation error (deg)", "focal error (px)", "principal point error (px)", "lever-arm error (cm)",
              "ray error (deg)")
    for ax, k, title in zip(fig.subplots(1, 5), ERRORS + ("ray_error_deg",), titles):
        ax.bar(range(len(summary)), summary[k], color=[colours.get(o, "tab:gray") for o in summary.objective])
        ax.axhline(summary[f"reference_{k}"].median(), color="tab:red", ls="--")
        ax.set_xticks(range(len(summary)), labels, rotation=90, fontsize=6)
        ax.set_title(title, fontsize=8)
    handles = [Patch(color=c, label=o) for o, c in colours.items() if o in set(summary.objective)]
    handles.append(Patch(color="tab:red", label="reference"))
    fig.legend(handles=handles, loc="upper right", fontsize=7, ncol=len(handles))
    fig.suptitle("Calibration error of CMA-ES's best point, median over seeds (synthetic, local space)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=150)
    fig.savefig(path.with_suffix(".pdf"))


COMPARED = ERRORS + ("ray_error_deg", "holdout_rmse_m")


def restored_seeds(folder: Path) -> int:
    """The finished jobs a configuration folder holds, its archive unpacked into it first (for
    make_identifiability.sh --seeds, which adds the seeds it lacks and packs again). A folder that an
    interrupted run left unpacked already holds its records: they are counted, never re-run."""
    if (folder / ARCHIVE).is_file():
        unpack(folder)
    return sum(1 for _ in folder.glob("synthetic/*/*/record.json"))


def compare_configs(runs: pd.DataFrame, a: str, b: str) -> pd.DataFrame:
    """Configurations a and b of ``runs`` (runs.csv's rows) paired by seed: per quantity of
    COMPARED, the medians, how often a is lower, the paired Wilcoxon p and that p Holm-adjusted
    over the quantities compared (a family of len(COMPARED)). Unknown names or no common seed:
    ValueError naming them."""
    known = set(runs.config)
    missing = [c for c in (a, b) if c not in known]
    if missing:
        raise ValueError(f"no runs of {missing} in runs.csv; configurations: {sorted(known)}")
    pair = runs[runs.config == a].merge(runs[runs.config == b], on="seed", suffixes=("_a", "_b"))
    if pair.empty:
        raise ValueError(f"{a} and {b} have no seed in common")
    rows = []
    for k in COMPARED:
        x, y = pair[f"{k}_a"].to_numpy(), pair[f"{k}_b"].to_numpy()
        _, _, p = stats.compare(x, y, paired=True)
        rows.append({"quantity": k, "median_a": np.median(x), "median_b": np.median(y),
                     "a_lower": f"{int((x < y).sum())}/{len(pair)}", "wilcoxon_p": p})
    table = pd.DataFrame(rows)
    table["holm_p"] = stats.holm(table.wilcoxon_p.to_numpy())
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--compare", nargs=2, metavar=("CONFIG_A", "CONFIG_B"),
                        help="compare two configurations of the folder's runs.csv seed by seed")
    parser.add_argument("--pack", action="store_true",
                        help="after the summary, pack each configuration's records into its records.tar.xz "
                             "without the evaluation logs (the summary reads only the records)")
    args = parser.parse_args()
    folder = args.folder
    if args.compare:
        a, b = args.compare
        try:
            if not (folder / "runs.csv").is_file():
                raise ValueError(f"{folder / 'runs.csv'} is absent (run the summary first)")
            table = compare_configs(pd.read_csv(folder / "runs.csv"), a, b)
        except ValueError as e:
            print(f"identifiability --compare: {e}", file=sys.stderr)
            raise SystemExit(2) from None
        print(f"A = {a}\nB = {b}, paired by seed\n" + table.to_string(index=False, float_format="%.4g"))
        return
    runs = load(folder)
    runs = runs.join(held_out(runs))
    runs.drop(columns=["params", "best_x"]).to_csv(folder / "runs.csv", index=False, float_format="%.6g")
    summary = summarise(runs, bounds_in(folder))
    summary.to_csv(folder / "summary.csv", index=False, float_format="%.4g")
    (folder / "summary.md").write_text(markdown(summary))
    figure(summary, folder / "summary.png")
    print(summary.to_string(index=False))
    if args.pack:
        for config in sorted(p for p in folder.iterdir() if p.is_dir() and has_records(p)):
            pack(config, remove=True, logs=False)


if __name__ == "__main__":
    main()
