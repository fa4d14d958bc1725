"""The objective along the straight line from the truth to a run's best point, with the filter's
update decisions counted: is the run's minimum a valley or a cell of luckier decisions?

studies/identifiability/minimiser_scatter.py predicts where the minimum of a K-drive objective lies from its
curvature at the truth; the identifiability study's runs end 2-3x farther out, every one below
f(truth). This script evaluates a run's own problem (its record's params, so its own drives) at
``truth + t (best - truth)`` in the run's space (``truth``: the problem's truth in that space,
frozen variables at the reference) and prints, per t, f - f(t=0) and the numbers of features the
updates used and rejected over all its drives. A jump of f between neighbouring t where only a
few decisions change says the minimum is a cell of the objective's piecewise-smooth surface, not
the bottom of a valley.

    python studies/identifiability/line_scan.py results/identifiability/innovation_nll_fourdrive_7free_1600evals_10seeds
        [--seeds 3] [--t 0 0.5 0.9 ...] [--fine 0.9 1.1 21] [--filter '{"outlier_decisions": "reference"}']
        [--along dx --span 0.24 13]

``--along VAR`` profiles the run's objective along one variable through its best point instead:
is the best point the minimum along it, and how rough is the objective there?
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.filter.batch import set_threads
from bench.archive import job_records
from bench.problems.synthetic import Synthetic
from bench.problems.vio import _plain

DEFAULT_T = (0.0, 0.2, 0.4, 0.6, 0.8, 0.9, 1.0, 1.1, 1.3)


def records(folder: Path, seeds: list[int] | None) -> list[dict]:
    """The finished synthetic records of one study configuration folder (those of ``seeds``)."""
    found = [r for _, r in job_records(folder, "synthetic/*/*/record.json")]  # files or records.tar.xz
    found = [r for r in found if r.get("status") == "ok" and (seeds is None or r["seed"] in seeds)]
    if not found:
        raise SystemExit(f"line_scan: {folder}: no finished synthetic record"
                         + ("" if seeds is None else f" of seeds {seeds}"))
    return sorted(found, key=lambda r: r["seed"])


def _problem(record: dict, filter_overrides: dict | None) -> Synthetic:
    """The record's own problem without its held-out drive (filter_overrides: FilterConfig
    settings over the record's)."""
    params = {k: _plain(v) for k, v in record["config"]["problem"]["params"].items()}
    if filter_overrides:
        params["filter"] = {**(params.get("filter") or {}), **filter_overrides}
    return Synthetic(**{**params, "holdout": None})  # the held-out drive plays no part


def _evaluate(problem: Synthetic, X: np.ndarray) -> dict[str, np.ndarray]:
    """f (n,) at the points X (n, d) of the problem's space (inside its bounds), and the
    features used and rejected over all its drives."""
    cal = problem.calibration_space.decode(X)
    results = [problem.run_filter(cal, drive) for drive in problem.drives]
    f, _ = problem.score_results(results, problem.drives)
    used = sum(r.n_updates.sum(axis=1) for r in results)
    rejected = sum(r.n_outliers.sum(axis=1) for r in results)
    return {"f": f, "used": used, "rejected": rejected}


def scan(record: dict, ts, filter_overrides: dict | None = None) -> dict[str, np.ndarray]:
    """(len(ts),) f, and the features used and rejected over all drives, along the line from
    the problem's truth (t = 0) to the record's best point (t = 1), clipped to the bounds."""
    problem = _problem(record, filter_overrides)
    x0, best = problem.truth, np.asarray(record["best_x"], float)
    X = np.clip(x0 + np.asarray(ts, float)[:, None] * (best - x0), problem.space.lower, problem.space.upper)
    return {"t": np.asarray(ts, float), **_evaluate(problem, X)}


def profile(record: dict, name: str, offsets, filter_overrides: dict | None = None) -> dict[str, np.ndarray]:
    """The same along one variable of the run's space through its best point: at
    ``best + offset e_name`` (offsets (n,) in the variable's unit); also the variable's error
    there, ``best + offset - truth`` (the bounds clip it)."""
    problem = _problem(record, filter_overrides)
    names = list(problem.space.names)
    if name not in names:
        raise SystemExit(f"line_scan: --along {name}: not a free variable of this run's space ({', '.join(names)})")
    i = names.index(name)
    X = np.repeat(np.asarray(record["best_x"], float)[None], len(offsets), axis=0)
    X[:, i] += np.asarray(offsets, float)
    X = np.clip(X, problem.space.lower, problem.space.upper)
    return {"error": X[:, i] - problem.truth[i], "unit": problem.space.units[i], **_evaluate(problem, X)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="one configuration folder of results/identifiability")
    parser.add_argument("--seeds", type=int, nargs="+", help="default: every seed in the folder")
    parser.add_argument("--t", type=float, nargs="+", default=list(DEFAULT_T), help="points along the line")
    parser.add_argument("--fine", type=float, nargs=3, metavar=("FROM", "TO", "N"),
                        help="instead of --t: N evenly spaced points (e.g. around the best point: 0.9 1.1 21)")
    parser.add_argument("--filter", type=json.loads, default=None,
                        help='FilterConfig settings over the record\'s, e.g. \'{"outlier_decisions": "reference"}\'')
    parser.add_argument("--along", metavar="VAR", help="instead of the line: the profile along this variable "
                        "through the best point (e.g. dx), at --span offsets")
    parser.add_argument("--span", type=float, nargs=2, metavar=("HALF_WIDTH", "N"), default=(0.24, 13),
                        help="--along: N offsets from -HALF_WIDTH to +HALF_WIDTH, in the variable's unit")
    args = parser.parse_args(argv)
    ts = np.linspace(args.fine[0], args.fine[1], int(args.fine[2])) if args.fine else np.asarray(args.t)
    ts = np.unique(np.r_[0.0, ts])  # t = 0 (the truth) is the baseline of f
    offsets = np.unique(np.r_[0.0, np.linspace(-args.span[0], args.span[0], int(args.span[1]))])
    set_threads(2)
    for record in records(args.folder, args.seeds):
        m = record["best_metrics"]
        print(f"seed {record['seed']}: best point {m['rotation_error_deg']:.2f} deg, "
              f"{m['principal_point_error_px']:.1f} px from the truth")
        if args.along:
            out = profile(record, args.along, offsets, args.filter)
            at_best = out["f"][np.flatnonzero(offsets == 0.0)[0]]
            for e, f, u, r in zip(out["error"], out["f"] - at_best, out["used"], out["rejected"]):
                print(f"  {args.along} error {e:+8.4f} {out['unit']}  f - f(best) {f:+.2e}  used {u:6d}  "
                      f"rejected {r:5d}")
            continue
        out = scan(record, ts, args.filter)
        for t, f, u, r in zip(out["t"], out["f"] - out["f"][0], out["used"], out["rejected"]):
            print(f"  t {t:5.2f}  f - f(0) {f:+.2e}  used {u:6d}  rejected {r:5d}")


if __name__ == "__main__":
    main()
