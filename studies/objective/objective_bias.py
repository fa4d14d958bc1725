"""Is the objectives' minimiser biased away from the truth calibration in expectation, or only
scattered by noise?

The identifiability study (results/identifiability, studies/identifiability/make_identifiability.sh) found,
under position_rmse with 4 drives, calibrations ~1 deg / 7.5 px / 23 cm from the truth that
score better than the truth on the held-out drive. Either the objective's expected optimum is
not the truth (a systematic error of the filter/objective) or the study overfitted its
calibration drives and was lucky on one held-out drive (variance). This script tells them
apart on fresh drives.

Method, per data seed s (the camera: its truth calibration is that of the seed's first drive,
exactly as bench/problems/synthetic.py builds it) and per noise setting (``--noise``):
M fresh paper_540m drives of that camera, ``simulate(config, (s, 100 + i), true_calibration=camera)``
for i < M (disjoint from the study's calibration drives s, (s, 1..3) and its held-out drive
(s, 1000)). Each drive runs ONE batch through the repo's machinery (VioProblem.score ->
avio.filter.run, avio.objectives) holding: the truth, the reference, the best calibration of
each of the 8 study configurations for this seed (decoded as studies/identifiability/identifiability.py does),
and the truth +- one step along each of the 10 local-space variables. From it:

1. the mean over the M drives of position_rmse (m) and innovation_nll (nats per residual) at
   the truth, the reference and the found calibrations, and the paired difference
   (found - truth) with its standard error over the drives. Found calibrations that beat the
   truth on fresh drives mean the objective's expected optimum is not the truth.
2. the slope at the truth of the M-drive mean objective along each variable (central
   difference, per drive, then mean, SE and t over the drives), the curvature from the same
   three points, and the implied 1-D offset of the expectation's minimum, -slope / curvature
   (+- SE / curvature; only where the curvature is clearly positive). Beside it, the mean offset
   (found - truth) over the seeds of the study's 4-drive 10-free CMA-ES runs under the same
   objective, to compare directions and sizes.
3. attribution: the same with the simulator's noise sources isolated by SimConfig overrides
   (``default``; ``pixel``: pixel noise and no IMU noise/bias, no outliers; ``imu``: IMU noise
   and biases only; ``none``: perfect data, studies/objective/check_objective.py's PERFECT).

    python studies/objective/objective_bias.py [--seeds 0 1 2 3 4] [--drives 16] [--noise default pixel imu none]

The filter runs on one thread (another session may share the machine).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "identifiability"))

from identifiability import best_calibrations, load

from avio.calibration import Calibration
from avio.filter.batch import set_threads
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import Synthetic

DRIVE = "paper_540m"
FRESH_SEED0 = 100  # second entropy word of the fresh drives: (s, 100 + i)
NOISE = {
    "default": {},
    "pixel": {"imu_noise_on": False, "outlier_fraction": 0.0},
    "imu": {"pixel_noise_px": 0.0, "outlier_fraction": 0.0},
    "none": {"imu_noise_on": False, "pixel_noise_px": 0.0, "outlier_fraction": 0.0},
}
NOISE_TEXT = {"default": "default noise (0.7 px, 5% outliers, IMU noise + biases)",
              "pixel": "pixel noise only (0.7 px; no IMU noise or bias, no outliers)",
              "imu": "IMU noise only (IMU noise + biases; 0 px, no outliers)",
              "none": "no noise (perfect data)"}
#: finite-difference step per local-space variable (~1/4 of the reference's error: px, deg, m)
STEP = {"fx": 0.5, "fy": 0.5, "cx": 0.5, "cy": 0.5, "rx": 0.1, "ry": 0.1, "rz": 0.1,
        "dx": 0.01, "dy": 0.01, "dz": 0.01}
#: how each variable is printed: (scale from the space's unit, printed unit)
SHOW = {"px": (1.0, "px"), "deg": (1.0, "deg"), "m": (100.0, "cm")}
OBJ = {"position_rmse": ("position_rmse_m", "m"), "innovation_nll": ("innovation_nll", "nats/res")}
#: per objective, the study configuration whose mean offset (best point - truth) is printed beside the slopes
STUDY_OFFSET_CONFIG = {"position_rmse": "position_rmse_fourdrive_10free",
                       "innovation_nll": "innovation_nll_fourdrive_10free"}


def study_calibrations(runs, data_seed: int, reference: Calibration, image_size) -> tuple[list[str], Calibration]:
    """The best calibration of every study configuration for this data seed (their names, the batch)."""
    group = runs[runs.data_seed == data_seed].sort_values("config")
    return list(group["config"]), best_calibrations(group, reference, image_size)


def evaluate_seed(seed: int, runs, noises: list[str], n_drives: int) -> dict:
    """Per noise setting: (M, n) both objectives and divergence flags of the batch
    [truth, reference, found..., truth + step e_j, truth - step e_j for j < 10]."""
    problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local")
    camera = problem.sequence.truth_calibration  # exactly SyntheticParams.build's camera
    reference = problem.sequence.reference_calibration
    names, found = study_calibrations(runs, seed, reference, problem.sequence.image_size_px)
    cs = problem.calibration_space
    x_truth = problem.truth
    h = np.array([STEP[n] for n in problem.space.names])
    plus = x_truth + np.diag(h)
    minus = x_truth - np.diag(h)
    batch = Calibration.stack([camera, reference, found, cs.decode(plus), cs.decode(minus)])
    out = {"names": names, "x_truth": x_truth, "x_found": cs.encode(found), "step": h,
           "space_names": problem.space.names, "units": problem.space.units}
    for noise in noises:
        config = getattr(SimConfig, DRIVE)(**NOISE[noise])
        config.validate()
        rmse, nll, div = [], [], []
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=camera)
            _, metrics = problem.score(batch, drives=(drive,))
            rmse.append(metrics["position_rmse_m"])
            nll.append(metrics["innovation_nll"])
            div.append(metrics["diverged"])
        out[noise] = {"position_rmse": np.array(rmse), "innovation_nll": np.array(nll),
                      "diverged": np.array(div)}
    return out


def mean_se(x: np.ndarray) -> tuple[float, float]:
    """The mean and its standard error (nan for one value)."""
    x = np.asarray(x, float)
    se = float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
    return float(x.mean()), se


def print_found(per_seed: dict, noise: str, detail: bool) -> None:
    """Part 1: mean objective at truth/reference/found on the fresh drives, paired found - truth."""
    seeds = sorted(per_seed)
    names = per_seed[seeds[0]]["names"]
    labels = ["reference"] + names
    print(f"  1. found calibrations on fresh drives: mean over drives; diff = (calibration - truth) +- SE "
          f"over drives, t = diff/SE (negative: beats the truth); wins: drives where it beats the truth "
          f"(rmse/nll), of M = {len(per_seed[seeds[0]][noise]['diverged'])} per seed; div: diverged filters")
    head = (f"  {'seed':>4} {'calibration':<33} {'rmse (m)':>9} {'diff (m)':>18} {'t':>6}   "
            f"{'nll (nats/res)':>14} {'diff (nats/res)':>20} {'t':>6}  wins  div")
    print(head)
    for s in (seeds if detail else []) + ["all"]:
        use = seeds if s == "all" else [s]
        vals = {k: np.concatenate([per_seed[u][noise][k] for u in use])
                for k in ("position_rmse", "innovation_nll", "diverged")}
        r0, n0 = vals["position_rmse"][:, 0], vals["innovation_nll"][:, 0]
        print(f"  {s!s:>4} {'truth':<33} {r0.mean():9.4f} {'':>18} {'':>6}   {n0.mean():14.5f}")
        for j, label in enumerate(labels, start=1):
            r, n = vals["position_rmse"][:, j], vals["innovation_nll"][:, j]
            dr, ser = mean_se(r - r0)
            dn, sen = mean_se(n - n0)
            ndiv = int(vals["diverged"][:, j].sum())
            wins = f"{int((r < r0).sum())}/{int((n < n0).sum())}"
            print(f"  {s!s:>4} {label:<33} {r.mean():9.4f} {dr:+9.4f} +- {ser:6.4f} {dr / ser:+6.1f}   "
                  f"{n.mean():14.5f} {dn:+10.5f} +- {sen:7.5f} {dn / sen:+6.1f}  {wins:>5} {ndiv}")


def print_slopes(per_seed: dict, noise: str, objective: str) -> None:
    """Part 2: per variable, slope of the mean objective at the truth, its t, and the implied offset."""
    seeds = sorted(per_seed)
    first = per_seed[seeds[0]]
    names, units, h = first["space_names"], first["units"], first["step"]
    d = len(names)
    unit_f = OBJ[objective][1]
    print(f"  2. slope at the truth, {objective} ({unit_f}); per-seed column: mean slope (t); 'all': over "
          f"every drive of every seed; offset = -slope/curvature, the implied 1-D minimum of the mean (- where the "
          f"curvature is not > 2 SE)")
    seed_cols = " ".join(f"{f'seed {s}':>16}" for s in seeds)
    print(f"  {'var':>4} {'step':>9} {seed_cols} {'all: slope':>12} {'+- SE':>9} {'t':>6} {'offset +- SE':>18} "
          f"{'study offset':>13}")
    for j, name in enumerate(names):
        scale, unit = SHOW[units[j]]
        cells = []
        slopes_all, curv_all = [], []
        for s in seeds:
            f = per_seed[s][noise][objective]
            f0, fp, fm = f[:, 0], f[:, 2 + len(first["names"]) + j], f[:, 2 + len(first["names"]) + d + j]
            slope = (fp - fm) / (2 * h[j] * scale)  # per printed unit
            curv = (fp + fm - 2 * f0) / (h[j] * scale) ** 2
            m, se = mean_se(slope)
            cells.append(f"{m:+9.2e} ({m / se:+5.1f})")
            slopes_all.append(slope)
            curv_all.append(curv)
        slope, curv = np.concatenate(slopes_all), np.concatenate(curv_all)
        m, se = mean_se(slope)
        c, c_se = mean_se(curv)
        # the 1-D quadratic's minimum, only where the curvature is clearly positive
        offset = f"{-m / c:+8.2g} +- {se / c:7.2g}" if c > 2 * c_se else f"{'-':>18}"
        line = f"  {name:>4} {h[j] * scale:5.2f} {unit:<3}" + " " + " ".join(f"{x:>16}" for x in cells)
        line += f" {m:+12.3e} {se:9.2e} {m / se:+6.1f} {offset}"
        config = STUDY_OFFSET_CONFIG[objective]
        offs = [per_seed[s]["x_found"][per_seed[s]["names"].index(config), j] - per_seed[s]["x_truth"][j]
                for s in seeds if config in per_seed[s]["names"]]
        line += f" {np.mean(offs) * scale:+13.3f}" if offs else ""
        print(f"{line}   {unit}")
    print(f"     (slopes in {unit_f} per printed unit; offset and study offset in the variable's printed unit; "
          f"study offset: mean over seeds of {STUDY_OFFSET_CONFIG[objective]}'s best point - truth)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--drives", type=int, default=16, help="fresh drives per seed (M)")
    parser.add_argument("--noise", nargs="+", choices=list(NOISE), default=["default", "pixel", "imu", "none"])
    parser.add_argument("--study", type=Path, default=ROOT / "results" / "identifiability")
    args = parser.parse_args()
    start = time.perf_counter()
    set_threads(1)
    runs = load(args.study)
    per_seed = {}
    for s in args.seeds:
        t = time.perf_counter()
        per_seed[s] = evaluate_seed(s, runs, args.noise, args.drives)
        print(f"(seed {s}: {args.drives} drives x {len(args.noise)} noise settings, "
              f"{time.perf_counter() - t:.0f} s)", flush=True)
    for k, noise in enumerate(args.noise):
        print(f"\n=== {NOISE_TEXT[noise]}: {len(args.seeds)} seeds x {args.drives} fresh {DRIVE} drives ===")
        print_found(per_seed, noise, detail=(k == 0))
        for objective in OBJ:
            print_slopes(per_seed, noise, objective)
    print(f"\nargs: {vars(args)}")
    print(f"total wall time {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
