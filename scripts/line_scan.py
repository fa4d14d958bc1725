"""The objective along the straight line from the truth to a run's best point, with the filter's
update decisions counted: is the run's minimum a valley or a cell of luckier decisions?

scripts/information_bound.py predicts where the minimum of a K-drive objective lies from its
curvature at the truth; the identifiability study's runs end 2-3x farther out, every one below
f(truth). This script evaluates a run's own problem (its record's params, so its own drives) at
``truth + t (best - truth)`` in the run's space (``truth``: the problem's truth in that space,
frozen variables at the reference) and prints, per t, f - f(t=0) and the numbers of features the
updates used and rejected over all its drives. A jump of f between neighbouring t where only a
few decisions change says the minimum is a cell of the objective's piecewise-smooth surface, not
the bottom of a valley.

    python scripts/line_scan.py results/identifiability/innovation_nll_fourdrive_7free_1600evals_10seeds
        [--seeds 3] [--t 0 0.5 0.9 ...] [--fine 0.9 1.1 21] [--filter '{"outlier_decisions": "reference"}']
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from avio.filter import set_threads  # noqa: E402
from bench.problems.synthetic import Synthetic  # noqa: E402
from bench.problems.vio import _plain  # noqa: E402

DEFAULT_T = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0, 1.1, 1.3)


def records(folder: Path, seeds: list[int] | None) -> list[dict]:
    """The finished synthetic records of one study configuration folder (those of ``seeds``)."""
    found = [json.loads(p.read_text()) for p in sorted(folder.glob("synthetic/*/seed*/record.json"))]
    found = [r for r in found if r.get("status") == "ok" and (seeds is None or r["seed"] in seeds)]
    if not found:
        raise SystemExit(f"line_scan: {folder}: no finished synthetic record"
                         + ("" if seeds is None else f" of seeds {seeds}"))
    return sorted(found, key=lambda r: r["seed"])


def scan(record: dict, ts, filter_overrides: dict | None = None) -> dict[str, np.ndarray]:
    """(len(ts),) f, and the features used and rejected over all drives, along the line from
    the problem's truth (t = 0) to the record's best point (t = 1), clipped to the bounds
    (filter_overrides: FilterConfig settings over the record's)."""
    params = {k: _plain(v) for k, v in record["config"]["problem"]["params"].items()}
    if filter_overrides:
        params["filter"] = {**(params.get("filter") or {}), **filter_overrides}
    problem = Synthetic(**{**params, "holdout": None})  # the held-out drive plays no part
    x0, best = problem.truth, np.asarray(record["best_x"], float)
    X = np.clip(x0 + np.asarray(ts, float)[:, None] * (best - x0), problem.space.lower, problem.space.upper)
    cal = problem.calibration_space.decode(X)
    f, _ = problem.score(cal)
    # run again for the decision counts: VioProblem.score keeps its FilterResults to itself (~2x a scan's cost)
    results = [problem.run_filter(cal, drive) for drive in problem.drives]
    used = sum(r.n_updates.sum(axis=1) for r in results)
    rejected = sum(r.n_outliers.sum(axis=1) for r in results)
    return {"t": np.asarray(ts, float), "f": f, "used": used, "rejected": rejected}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="one configuration folder of results/identifiability")
    parser.add_argument("--seeds", type=int, nargs="+", help="default: every seed in the folder")
    parser.add_argument("--t", type=float, nargs="+", default=list(DEFAULT_T), help="points along the line")
    parser.add_argument("--fine", type=float, nargs=3, metavar=("FROM", "TO", "N"),
                        help="instead of --t: N evenly spaced points (e.g. around the best point: 0.9 1.1 21)")
    parser.add_argument("--filter", type=json.loads, default=None,
                        help='FilterConfig settings over the record\'s, e.g. \'{"outlier_decisions": "reference"}\'')
    args = parser.parse_args(argv)
    ts = np.linspace(args.fine[0], args.fine[1], int(args.fine[2])) if args.fine else np.asarray(args.t)
    ts = np.unique(np.r_[0.0, ts])  # t = 0 (the truth) is the baseline of f
    set_threads(2)
    for record in records(args.folder, args.seeds):
        out = scan(record, ts, args.filter)
        m = record["best_metrics"]
        print(f"seed {record['seed']}: best point {m['rotation_error_deg']:.2f} deg, "
              f"{m['principal_point_error_px']:.1f} px from the truth")
        for t, f, u, r in zip(out["t"], out["f"] - out["f"][0], out["used"], out["rejected"]):
            print(f"  t {t:5.2f}  f - f(0) {f:+.2e}  used {u:6d}  rejected {r:5d}")


if __name__ == "__main__":
    main()
