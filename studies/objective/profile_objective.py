"""Is the objective informative? Profile it along each calibration variable.

    python studies/objective/profile_objective.py problem=synthetic [--points 21] [--out results/synthetic/profile]

Evaluates the VIO position RMSE along each variable of the problem's space across its bounds
(Table 1 for the paper space), the other variables at the truth (the reference when the truth
is unknown; a truth outside the bounds is profiled and flagged), and writes ``profile.csv`` and
``profile.png`` (linear scale, truth and reference marked, PDF beside). It also prints, per variable, how
much the objective rises over the central 10% of the range around the truth and where its
minimum lies: a flat profile or a minimum far from the truth means the objective does not
determine that variable.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.problems.base import build_problem
from bench.report.paper.artifacts import objective_profile, space_info
from bench.report.paper.figures import profile_figure
from bench.run.preflight import compose_job


def summarise(profile, problem) -> None:
    print(f"{'variable':>8} {'f(anchor)':>10} {'rise@5%':>9} {'argmin - anchor':>16}  (units of the variable)")
    for i, name in enumerate(problem.space.names):
        part = profile[profile["variable"] == name]
        width = problem.space.upper[i] - problem.space.lower[i]
        f0 = part.loc[part["offset"].abs().idxmin(), "f"]
        near = part[(part["offset"].abs() <= 0.05 * width + 1e-12)]
        rise = near["f"].max() - f0
        argmin = part.loc[part["f"].idxmin(), "offset"]
        print(f"{name:>8} {f0:10.3f} {rise:9.3f} {argmin:16.4g}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. problem=kitti00")
    parser.add_argument("--points", type=int, default=21)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    cfg = compose_job(args.overrides)
    problem = build_problem(cfg)
    out = args.out or Path("results") / problem.name / "profile"
    out.mkdir(parents=True, exist_ok=True)
    profile = objective_profile(problem, args.points)
    profile.to_csv(out / "profile.csv", index=False, float_format="%.6g")
    profile_figure(profile, space_info(problem), out / "profile.png", getattr(problem, "objective", "position_rmse"))
    summarise(profile, problem)
    print(f"wrote {out / 'profile.csv'} and {out / 'profile.png'}")


if __name__ == "__main__":
    main()
