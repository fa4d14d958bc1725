"""Where does the exact minimum of one objective over K calibration drives fall? The scatter of
the objective's minimiser, predicted from its curvature and its drive-to-drive gradient noise.

Not a bound on what the data allow (named information_bound.py until issue 33): it predicts this
objective's minimiser, whatever its efficiency; the Cramér–Rao bound of what any unbiased
estimator can reach is studies/identifiability/cramer_rao.py. A configuration's frozen variables
set floors of their own (the 7-free space's lever arm: dy, dz frozen at the reference).

The identifiability study (results/identifiability) finds its best runs below f(truth) and yet
0.2-1.4 deg from the truth: the objective's minimum on those drives is there. This script says
how far the minimum of a K-drive objective lies from the truth in expectation, so that a target
can be judged reachable or not before any optimiser runs.

Method (the textbook M-estimator "sandwich"): on M fresh paper_540m drives of each data seed's
camera (``simulate(config, (s, 100 + i), true_calibration=camera)``, as
studies/objective/objective_bias.py), one batch per drive holds the truth and a central-difference design
around it in the full 10-variable local space (steps STEP: ``x_t``, ``x_t +- h_i e_i``,
``x_t +- h_i e_i +- h_j e_j``). Per drive: the gradient g (10,) and Hessian (10, 10) at the truth
of the additive per-drive objective (``position_rmse``: its square, the mean squared error that
the pooled RMSE of K drives is the root of; ``innovation_nll``: itself, nats per residual). Over
all drives: the mean Hessian H, the mean gradient gbar (the objective's own tilt at the truth)
and the gradients' covariance G. The K-drive objective is then
``F(x) ~ (gbar + eps)^T (x - x_t) + 1/2 (x - x_t)^T H (x - x_t)`` with ``eps ~ N(0, G / K)``; a
configuration with variables frozen at the reference or tied (fy = fx) searches the affine
subspace ``x = A y + c`` (read off its calibration space), whose minimum is
``y* = -(A^T H A)^-1 A^T (gbar + eps + H (c' - x_t))`` (c' the subspace point nearest the
origin of y). Drawing eps gives the minimiser's distribution per camera, turned into the study's
calibration errors (avio.calibration) against that seed's truth, and, by drawing one run
per seed and taking the median over the seeds, the distribution of the study's median.

    python studies/identifiability/minimiser_scatter.py [--seeds 0 1 2 3 4] [--drives 16] [--predict-seeds 0..9]

The quadratic model holds near the truth (steps STEP, the size of the scatter it predicts); where
the objective is rough (the likelihood's gate decisions) G carries that roughness at the step's
scale, as an optimiser sees it. About 8 min for 80 drives on 2 threads.
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from objective_bias import DRIVE, FRESH_SEED0

from avio.calibration import calibration_errors, ray_error_deg
from avio.filter.batch import set_threads
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import Synthetic

#: central-difference step per local-space variable (px, deg, m), about the size of the scatter
#: to be predicted: with a third of it the mean Hessians over 80 drives are not positive definite
#: along the weak directions (the objectives' roughness between nearby points dominates there)
STEP = {"fx": 3.0, "fy": 3.0, "cx": 3.0, "cy": 3.0, "rx": 0.3, "ry": 0.3, "rz": 0.3,
        "dx": 0.03, "dy": 0.03, "dz": 0.03}
#: the study's configurations: name -> (tie_focal, fixed variables)
CONFIGS = {"10 free": (False, []), "7 free": (True, ["dy", "dz"]), "5 free": (True, ["cx", "cy", "dy", "dz"])}
#: the per-drive objective whose mean the K-drive objective is (see the module docstring)
OBJECTIVES = {"position_rmse": lambda m: m["position_rmse_m"] ** 2, "innovation_nll": lambda m: m["innovation_nll"]}
ERRORS = ("rotation_error_deg", "focal_error_px", "principal_point_error_px", "translation_error_cm")
#: issue 11's targets for the 4-drive calibration (rotation deg, focal px, lever arm cm)
TARGETS = {"rotation_error_deg": 0.2, "focal_error_px": 1.5, "translation_error_cm": 3.0}


def design(n: int, h: np.ndarray) -> np.ndarray:
    """(1 + 2n + 2n(n-1), n) offsets: 0, +-h_i e_i, then (+h_i, +h_j), (+, -), (-, +), (-, -) per i < j."""
    rows = [np.zeros(n)]
    for i in range(n):
        for s in (1.0, -1.0):
            rows.append(s * h[i] * np.eye(n)[i])
    for i in range(n):
        for j in range(i + 1, n):
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                rows.append(si * h[i] * np.eye(n)[i] + sj * h[j] * np.eye(n)[j])
    return np.array(rows)


def derivatives(f: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (n, ...) and Hessian (n, n, ...) from the values f (n_points, ...) at :func:`design`'s
    points (trailing axes of f, e.g. frames, carried through)."""
    n = len(h)
    f = np.asarray(f, float)
    hh = h.reshape((n,) + (1,) * (f.ndim - 1))
    f0, axis = f[0], f[1:1 + 2 * n].reshape((n, 2) + f.shape[1:])
    g = (axis[:, 0] - axis[:, 1]) / (2 * hh)
    H = np.zeros((n, n) + f.shape[1:])
    H[np.arange(n), np.arange(n)] = (axis[:, 0] + axis[:, 1] - 2 * f0) / hh**2
    k = 1 + 2 * n
    for i in range(n):
        for j in range(i + 1, n):
            pp, pm, mp, mm = f[k:k + 4]
            H[i, j] = H[j, i] = (pp - pm - mp + mm) / (4 * h[i] * h[j])
            k += 4
    return g, H


def measure(seeds, n_drives: int, step_scale: float = 1.0) -> dict:
    """Per objective: (D, 10) gradients and (D, 10, 10) Hessians at the truth over the D fresh
    drives (those where no filter of the batch diverged); the space's names and steps."""
    out = {k: {"g": [], "H": []} for k in OBJECTIVES}
    skipped = 0
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local")
        camera = problem.sequence.truth_calibration
        h = step_scale * np.array([STEP[n] for n in problem.space.names])
        batch = problem.calibration_space.decode(problem.truth + design(len(h), h))
        for i in range(n_drives):
            drive = simulate(getattr(SimConfig, DRIVE)(), (seed, FRESH_SEED0 + i), true_calibration=camera)
            _, metrics = problem.score(batch, drives=(drive,))
            if metrics["diverged"].any():
                skipped += 1
                continue
            for name, value in OBJECTIVES.items():
                g, H = derivatives(value(metrics), h)
                out[name]["g"].append(g)
                out[name]["H"].append(H)
    for k in OBJECTIVES:
        out[k] = {key: np.array(v) for key, v in out[k].items()}
    out["names"], out["step"], out["skipped"] = problem.space.names, h, skipped
    return out


def subspace(full: Synthetic, tie_focal: bool, fixed: list[str], seed: int):
    """(A (10, r), c (10,)) of a configuration's space inside the full local space: full
    coordinates ``A y + c`` of its coordinates y (affine: read off by unit steps)."""
    sub = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local", tie_focal=tie_focal, fixed=fixed)
    y0 = sub.truth
    cols = [full.calibration_space.encode(sub.calibration_space.decode((y0 + e)[None]))[0] for e in np.eye(len(y0))]
    x0 = full.calibration_space.encode(sub.calibration_space.decode(y0[None]))[0]
    A = np.array(cols).T - x0[:, None]
    return A, x0 - A @ y0


@lru_cache(maxsize=None)
def _camera(seed: int) -> Synthetic:
    """The full-space problem of one camera (built once: predict runs per K and configuration)."""
    return Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local")


@lru_cache(maxsize=None)
def _camera_subspace(seed: int, tie_focal: bool, fixed: tuple[str, ...]):
    return subspace(_camera(seed), tie_focal, list(fixed), seed)


def predict(g: np.ndarray, H: np.ndarray, K: int, configs, seeds, draws: int, rng) -> dict:
    """Per configuration: (len(seeds), draws) calibration errors (and ray errors) of the K-drive
    minimiser, per error name."""
    Hm, gbar = H.mean(axis=0), g.mean(axis=0)
    Hm = 0.5 * (Hm + Hm.T)
    cov = np.cov(g.T) / K
    out = {}
    for label, (tie, fixed) in configs.items():
        per = {k: [] for k in (*ERRORS, "ray_error_deg")}
        for seed in seeds:
            full = _camera(seed)
            x_t = full.truth
            A, c = _camera_subspace(seed, tie, tuple(fixed))
            Hs = A.T @ Hm @ A
            if np.linalg.eigvalsh(Hs)[0] <= 0:  # a direction without a minimum: the bounds decide
                for k in per:
                    per[k].append(np.full(draws, np.nan))
                continue
            eps = rng.multivariate_normal(np.zeros(len(x_t)), cov, size=draws, method="eigh")
            rhs = (gbar + eps + Hm @ (c - x_t)) @ A  # (draws, r): A^T (...)
            y = -np.linalg.solve(Hs, rhs.T).T
            cal = full.calibration_space.decode(y @ A.T + c)
            truth = full.sequence.truth_calibration
            errs = calibration_errors(cal, truth)
            for k in ERRORS:
                per[k].append(errs[k])
            per["ray_error_deg"].append(ray_error_deg(cal, truth, full.sequence.image_size_px))
        out[label] = {k: np.array(v) for k, v in per.items()}
    return out


def study_median(errors: np.ndarray, rng, n_studies: int = 4000) -> tuple[float, float, float]:
    """The study's median over its seeds (one run per seed) when each seed's run is a draw of
    ``errors`` (n_seeds, draws): its median and 5-95 % range over ``n_studies`` replays."""
    n_seeds, draws = errors.shape
    pick = rng.integers(0, draws, size=(n_studies, n_seeds))
    medians = np.median(errors[np.arange(n_seeds), pick], axis=1)
    return float(np.median(medians)), float(np.quantile(medians, 0.05)), float(np.quantile(medians, 0.95))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras measured")
    parser.add_argument("--drives", type=int, default=16, help="fresh drives per camera")
    parser.add_argument("--predict-seeds", type=int, nargs="+", default=list(range(10)),
                        help="the cameras of the predicted study (their truth and reference set the frozen offsets)")
    parser.add_argument("--K", type=int, nargs="+", default=[1, 4, 16, 64], help="calibration drives")
    parser.add_argument("--draws", type=int, default=2000)
    parser.add_argument("--step-scale", type=float, default=1.0, help="multiply every finite-difference step")
    parser.add_argument("--save", type=Path, help="write the measured gradients and Hessians (.npz)")
    parser.add_argument("--load", type=Path, help="predict from a --save file instead of measuring")
    args = parser.parse_args(argv)
    set_threads(2)
    start = time.perf_counter()
    if args.load:
        saved = np.load(args.load, allow_pickle=False)
        data = {k: {"g": saved[f"{k}_g"], "H": saved[f"{k}_H"]} for k in OBJECTIVES}
        data.update(names=tuple(saved["names"]), step=saved["step"], skipped=int(saved["skipped"]))
    else:
        data = measure(args.seeds, args.drives, args.step_scale)
    if args.save:
        np.savez(args.save, names=np.array(data["names"]), step=data["step"], skipped=data["skipped"],
                 **{f"{k}_{q}": data[k][q] for k in OBJECTIVES for q in ("g", "H")})
    n = len(data["innovation_nll"]["g"])
    print(f"{n} fresh drives of cameras {args.seeds} ({data['skipped']} skipped: a filter diverged), "
          f"{len(design(10, data['step']))} calibrations each, {time.perf_counter() - start:.0f} s")
    rng = np.random.default_rng(0)
    for objective in OBJECTIVES:
        g, H = data[objective]["g"], data[objective]["H"]
        Hm = 0.5 * (H.mean(axis=0) + H.mean(axis=0).T)
        scale = data["step"]  # eigen-analysis in units of the steps, so the variables are comparable
        w, V = np.linalg.eigh(Hm * np.outer(scale, scale))
        flat = V[:, 0]
        per_drive = np.einsum("i,dij,j->d", flat * scale, H, flat * scale)  # its curvature on each drive
        print(f"\n{objective}: mean Hessian's eigenvalues per step^2 {np.array2string(w, precision=2)}; "
              f"the flattest direction (per step): " + ", ".join(
                  f"{name} {v:+.2f}" for name, v in zip(data["names"], flat) if abs(v) >= 0.2)
              + f"; its curvature {per_drive.mean():+.2e} +- {per_drive.std(ddof=1) / np.sqrt(len(per_drive)):.1e} (SE)")
        t = g.mean(axis=0) / (g.std(axis=0, ddof=1) / np.sqrt(len(g)))
        print("  mean gradient at the truth, t over the drives: "
              + ", ".join(f"{name} {v:+.1f}" for name, v in zip(data["names"], t)))
        print(f"  predicted study medians over cameras {args.predict_seeds[0]}-{args.predict_seeds[-1]} "
              "(median [5-95 % of replays]); P = share of runs meeting all three 4-drive targets:")
        print("  | configuration | K | " + " | ".join(ERRORS + ("ray_error_deg",)) + " | P |")
        for K in args.K:
            pred = predict(g, H, K, CONFIGS, args.predict_seeds, args.draws, rng)
            for label, errs in pred.items():
                if np.isnan(errs["rotation_error_deg"]).any():
                    print(f"  | {label} | {K} | not determined: the mean Hessian has a direction without curvature there |")
                    continue
                cells = []
                for k in (*ERRORS, "ray_error_deg"):
                    m, lo, hi = study_median(errs[k], rng)
                    cells.append(f"{m:.2f} [{lo:.2f}-{hi:.2f}]")
                meets = np.ones(errs["rotation_error_deg"].shape, bool)
                for k, bound in TARGETS.items():
                    meets &= errs[k] <= bound
                print(f"  | {label} | {K} | " + " | ".join(cells) + f" | {meets.mean():.2f} |")


if __name__ == "__main__":
    main()
