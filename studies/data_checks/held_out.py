"""Do the optimisers' calibrations beat the reference calibration on the held-out drives? Paired over instances.

    python studies/data_checks/held_out.py results/<set> [--out FILE.csv]

For every instance of a committed sweep (files or records.tar.xz): the problem rebuilt from the
records' config (its held-out drive: synthetic's ``holdout`` preset with the instance's camera,
kitti00's and euroc's held-out windows), and one batch on that drive holding each optimiser's best
calibration, the reference and (where known) the truth. Per optimiser: the median held-out
position RMSE (m), in how many instances it is below the reference's, and the paired two-sided
Wilcoxon signed-rank p against the reference, Holm-adjusted over the optimisers (the report's
paired test, ``bench.report.stats``). The report's Table 3 shows the first instance only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.calibration import Calibration
from bench.archive import job_records
from bench.problems.base import build_problem
from bench.report import stats


def held_out_rmse(folder: Path) -> pd.DataFrame:
    """One row per instance and calibration (each optimiser's best, ``reference``, ``truth``):
    the held-out drive's position RMSE (m)."""
    records = [r for _, r in job_records(folder) if r.get("status") == "ok" and r.get("best_x") is not None]
    if not records:
        raise SystemExit(f"held_out: {folder}: no finished records")
    rows = []
    for instance in sorted({r["instance"] for r in records}):
        group = [r for r in records if r["instance"] == instance]
        problem = build_problem(group[0]["config"])
        if problem.holdout is None:
            raise SystemExit(f"held_out: {folder}: problem {problem.name} has no held-out drive")
        space = problem.calibration_space
        found = space.decode(np.array([r["best_x"] for r in group], float))
        anchors = [problem.reference_calibration] + ([problem.sequence.truth_calibration]
                                                     if problem.sequence.truth_calibration is not None else [])
        _, metrics = problem.score(Calibration.stack([found, *anchors]), (problem.holdout,))
        names = [r["optimizer"] for r in group] + ["reference", "truth"][:len(anchors)]
        rows += [{"instance": instance, "calibration": n, "holdout_rmse_m": float(v)}
                 for n, v in zip(names, metrics["position_rmse_m"])]
    return pd.DataFrame(rows)


def against_reference(table: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser: median held-out RMSE, instances below the reference, paired Wilcoxon p (Holm)."""
    wide = table.pivot(index="instance", columns="calibration", values="holdout_rmse_m")
    out = []
    for name in [c for c in wide.columns if c not in ("reference", "truth")]:
        pair = wide[[name, "reference"]].dropna()
        _, _, p = stats.compare(pair[name].to_numpy(), pair["reference"].to_numpy(), paired=True)
        out.append({"optimizer": name, "instances": len(pair), "median_m": pair[name].median(),
                    "reference_median_m": pair["reference"].median(),
                    "truth_median_m": wide["truth"].median() if "truth" in wide else np.nan,
                    "below_reference": int((pair[name] < pair["reference"]).sum()), "p": p})
    result = pd.DataFrame(out).sort_values("median_m")
    result["p_holm"] = stats.holm(result["p"].to_numpy())
    return result


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--out", type=Path, help="also write the per-instance values (CSV)")
    args = parser.parse_args(argv)
    table = held_out_rmse(args.folder)
    if args.out:
        table.to_csv(args.out, index=False, float_format="%.6g")
    print(against_reference(table).to_string(index=False, float_format=lambda v: f"{v:.4g}"))


if __name__ == "__main__":
    main()
