"""Is the objective's optimum the truth? The invariants and figures of issue 11, printed.

    python studies/objective/check_objective.py [--seeds 20] [--profile-points 21] [--drives 1 4]

1. Perfect data (noise-free IMU, 0 px, no outliers) on the default 540 m drive with its stop:
   f(truth) under the position RMSE, and where each variable's 1-D profile has its minimum
   (a parabola through the three lowest grid points, the others at the truth).
2. Consistency at the truth on ``synthetic`` (default noise): NIS per degree of freedom of the
   updates and the median position NEES (per-axis, with the filter's own sigmas), per seed.
3. Truth against the reference over ``--seeds`` data seeds, under each objective; where the
   reference wins, its ray error there against where it loses (one-sided Mann-Whitney); then
   the same with each objective over ``--drives`` drives of each seed's camera (3b; default 4:
   the multi-drive objective of the identifiability study).
4. When ``results/identifiability/summary.csv`` exists: the identifiability study's table.
5. When the committed all-real sweeps exist (results/kitti00_tracks, results/kitti00_tracks_nll, and
   their *_rotation variants, which calibrate the rotation alone):
   how far each optimiser's best rotation lies from the rectified KITTI extrinsic (the local
   space's rotation vector is the offset from it), under each objective, and its ray error
   against the rectified KITTI calibration (avio.calibration.ray_error_deg); then how far
   the rectified extrinsic itself lies from the orientation the tracks imply against the ground
   truth's calibration chain, and the rotation-only likelihood from that
   (studies/data_checks/check_kitti_extrinsic.py, PnP, frames 15-153).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.calibration import ray_error_deg
from avio.objectives import OBJECTIVES
from bench.problems.synthetic import Synthetic

PERFECT = {"imu_noise_on": False, "pixel_noise_px": 0.0, "outlier_fraction": 0.0}
#: half-width of each profile around the truth (px, deg, m in the paper space's order)
HALF = {"fx": 2.0, "fy": 2.0, "cx": 2.0, "cy": 2.0, "roll": 0.1, "pitch": 0.1, "yaw": 0.1,
        "tx": 0.02, "ty": 0.02, "tz": 0.02}


def perfect_data(points: int) -> None:
    problem = Synthetic(holdout=None, sim=PERFECT)
    n_stationary = int(problem.prepared(problem.sequence).stationary.sum())
    print(f"1. perfect data, default drive ({problem.sequence.n_frames} frames, {n_stationary} standstill frames):"
          f" f(truth) = {problem.f_truth:.4f} m, f(reference) = {problem.f_reference:.3f} m")
    names, truth = problem.space.names, problem.truth
    grids = [truth[i] + np.linspace(-HALF[n], HALF[n], points) for i, n in enumerate(names)]
    X = np.repeat(truth[None], points * len(names), axis=0)
    for i, g in enumerate(grids):
        X[i * points:(i + 1) * points, i] = g
    X = np.clip(X, problem.space.lower, problem.space.upper)
    f, _ = problem.evaluate(X)
    for i, n in enumerate(names):
        fi, g = f[i * points:(i + 1) * points], X[i * points:(i + 1) * points, i]
        k = int(np.clip(np.argmin(fi), 1, points - 2))
        a, b, _ = np.polyfit(g[k - 1:k + 2] - truth[i], fi[k - 1:k + 2], 2)
        at = -b / (2 * a) if a > 0 else g[k] - truth[i]
        rise = fi.max() - fi.min()
        unit = problem.space.units[i]
        if rise < 1e-4:  # flat: the drive does not determine this variable (PAPER.md §6)
            print(f"   {n:>5}: flat (rise over +-{HALF[n]} {unit}: {rise:.1e} m): not determined by this drive")
            continue
        print(f"   {n:>5}: profile minimum {at:+.4f} {unit} from the truth (rise over +-{HALF[n]} {unit}: {rise:.4f} m)")


def losers_by_ray_error(truth_better: np.ndarray, ray_deg: np.ndarray) -> dict:
    """Do the seeds where the reference beats the truth have a reference that casts nearly the
    truth's rays? truth_better (n,) bool, ray_deg (n,) the reference's ray error per seed:
    the losing seeds, the median ray error of the winning ones and the one-sided Mann-Whitney
    p-value of "the losers' ray errors are smaller" (None when either group is empty)."""
    truth_better, ray_deg = np.asarray(truth_better, bool), np.asarray(ray_deg, float)
    lost = np.flatnonzero(~truth_better)
    p = None
    if 0 < len(lost) < len(ray_deg):
        from scipy.stats import mannwhitneyu

        p = float(mannwhitneyu(ray_deg[lost], ray_deg[truth_better], alternative="less").pvalue)
    won = ray_deg[truth_better]
    return {"lost": lost, "lost_ray_deg": ray_deg[lost], "won_median_ray_deg": float(np.median(won)) if len(won) else None,
            "p": p}


def consistency_and_ranking(seeds: int, drives=(1,)) -> None:
    from scipy.stats import chi2

    rows, rays = [], []
    for seed in range(seeds):
        problem = Synthetic(holdout=None, data_seed=seed)
        cal, ref = problem.sequence.truth_calibration, problem.sequence.reference_calibration
        anchors = type(cal).stack([cal, ref])
        rays.append(float(ray_error_deg(ref, cal, problem.sequence.image_size_px)[0]))
        result = problem.run_filter(anchors)
        err = result.p_world_imu_m[0] - problem.sequence.truth.p_world_imu_m
        nees = float(np.median(np.sum((err / result.sigma[0, :, :3]) ** 2, axis=1)))
        _, metrics = problem.score(anchors)
        rows.append((seed, metrics["nis_per_dof"][0], nees, *(metrics[k] for k in ("position_rmse_m", "innovation_nll"))))
    print("2. consistency at the truth (synthetic, default noise):")
    nis = np.array([r[1] for r in rows])
    nees = np.array([r[2] for r in rows])
    print(f"   NIS/dof median {np.median(nis):.3f} (range {nis.min():.3f}-{nis.max():.3f}); "
          f"position NEES median over seeds {np.median(nees):.2f} (range {nees.min():.2f}-{nees.max():.2f}; "
          f"{chi2.median(3):.2f} expected: the median of chi-square with 3 degrees of freedom, whose mean is 3)")
    print(f"3. truth against reference over {seeds} data seeds:")
    _print_ranking([[r[3 + j] for r in rows] for j in range(2)], np.array(rays))
    for n in drives:
        if n > 1:
            print(f"3b. the same with each objective over {n} drives of each seed's camera (problem.params.drives):")
            _print_ranking(_ranking(seeds, n), np.array(rays))  # the same cameras: the same ray errors


def _ranking(seeds: int, n_drives: int) -> list:
    """Both objectives at (truth, reference) of each seed's camera over n_drives drives:
    f[j][seed] (2,)."""
    f = [[], []]
    for seed in range(seeds):
        problem = Synthetic(drives=("paper_540m",) * n_drives, holdout=None, data_seed=seed)
        cal, ref = problem.sequence.truth_calibration, problem.sequence.reference_calibration
        _, metrics = problem.score(type(cal).stack([cal, ref]))
        for j, name in enumerate(("position_rmse_m", "innovation_nll")):
            f[j].append(metrics[name])
    return f


def _print_ranking(f: list, rays: np.ndarray) -> None:
    """f[j][seed] = (objective j at the truth, at the reference): wins, medians, and where the
    reference wins, its ray error against where it loses."""
    seeds = len(rays)
    for j in range(2):
        truth = np.array([pair[0] for pair in f[j]])
        ref = np.array([pair[1] for pair in f[j]])
        wins = int(np.sum(truth < ref))
        print(f"   {OBJECTIVES[j]:>14}: truth better in {wins}/{seeds} seeds; "
              f"median truth {np.median(truth):.4f}, reference {np.median(ref):.4f}, paired difference "
              f"{np.median(ref - truth):+.4f}")
        s = losers_by_ray_error(truth < ref, rays)
        if s["p"] is not None:
            print(f"   {'':>14}  lost in seeds {', '.join(map(str, s['lost']))}, where the reference's ray error is "
                  f"{', '.join(f'{r:.2f}' for r in s['lost_ray_deg'])} deg against a median {s['won_median_ray_deg']:.2f} deg "
                  f"where the truth wins (one-sided Mann-Whitney p = {s['p']:.3f})")


def identifiability_summary() -> None:
    path = ROOT / "results" / "identifiability" / "summary.csv"
    if not path.is_file():
        print(f"4. {path.relative_to(ROOT)} not found "
              f"(make it with bash studies/identifiability/make_identifiability.sh)")
        return
    import pandas as pd

    print("4. identifiability study (results/identifiability/summary.csv):")
    print(pd.read_csv(path).to_string(index=False))


def real_track_rotations() -> None:

    from bench.archive import job_records
    from bench.problems.base import build_problem

    print("5. kitti00_tracks: best rotation's angle from the rectified KITTI extrinsic (median over seeds):")
    for name in ("kitti00_tracks", "kitti00_tracks_nll", "kitti00_tracks_rotation", "kitti00_tracks_nll_rotation"):
        records = [r for _, r in job_records(ROOT / "results" / name)]  # files or records.tar.xz
        records = [r for r in records if r.get("status") == "ok"]
        if not records:
            print(f"   results/{name}: no records")
            continue
        by_opt: dict[str, list[float]] = {}
        rays: dict[str, list[float]] = {}
        for r in records:
            x = dict(zip(r["space"]["names"], r["best_x"]))
            by_opt.setdefault(r["optimizer"], []).append(float(np.linalg.norm([x["rx"], x["ry"], x["rz"]])))
            problem = build_problem(r["config"])
            cal = problem.calibration_space.decode(np.asarray(r["best_x"], float)[None])
            trusted = problem.sequence.reference_calibration  # the rectified KITTI calibration (no truth here)
            rays.setdefault(r["optimizer"], []).append(
                float(ray_error_deg(cal, trusted, problem.sequence.image_size_px)[0]))
        objective = records[0]["config"]["problem"]["params"]["objective"]
        for opt, angles in sorted(by_opt.items()):
            print(f"   {name:>27} ({objective}) {opt:>5}: {np.median(angles):.2f} deg (seeds: {', '.join(f'{a:.2f}' for a in angles)});"
                  f" ray error {np.median(rays[opt]):.2f} deg (seeds: {', '.join(f'{a:.2f}' for a in rays[opt])})")
    sys.path.insert(0, str(ROOT / "studies" / "data_checks"))
    import check_kitti_extrinsic as cke  # studies/data_checks/check_kitti_extrinsic.py

    from bench.problems.vio import default_data_dir

    data = default_data_dir()
    if not (data / "kitti00" / cke.TRACKS_FILE).exists():
        print(f"   {data / 'kitti00' / cke.TRACKS_FILE}: not found, no check of the rectified extrinsic")
        return
    d = cke.direction_offsets(data, 15, 153, method="pnp")
    dx, dy = cke.chain_correction_deg(d)
    print(f"   the tracks against the ground truth's chain (PnP, frames 15-153, {len(d)} pairs): the rectified extrinsic "
          f"is off by ({dx:+.2f}, {dy:+.2f}, ?) deg, {np.hypot(dx, dy):.2f} deg before its part about the optical axis")
    for v in cke.committed_likelihood_corrections(ROOT / "results" / "kitti00_tracks_nll_rotation")[:1]:
        print(f"   the rotation-only likelihood's correction ({v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f}) deg lies "
              f"{np.hypot(v[0] - dx, v[1] - dy):.2f} deg from it")



def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--profile-points", type=int, default=21)
    parser.add_argument("--drives", type=int, nargs="+", default=[1, 4],
                        help="section 3 with each objective over this many drives per camera (1: section 2's drive)")
    args = parser.parse_args()
    start = time.perf_counter()
    perfect_data(args.profile_points)
    consistency_and_ranking(args.seeds, args.drives)
    identifiability_summary()
    real_track_rotations()
    print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
