"""Where the information-matrix excess of the joint likelihood comes from: the drive's score split
into its updates' scores, and their covariance by lag (issue 33).

The joint innovation NLL of a drive is a sum over update frames, ``l = sum_k l_k`` (docs/model.md,
Eq. 55a). If the filter were the exact conditional model of the data, each update's score
``g_k = d l_k / d x`` at the true x would have mean zero given the past (the prediction-error
decomposition): the scores of different updates are uncorrelated, so the drive's gradient
covariance ``G = Cov(sum_k g_k)`` is the sum of the per-update covariances, and it equals the mean
Hessian H. Splitting

    G = C(0) + sum_{lag >= 1} (C(lag) + C(lag)^T),   C(lag) = sum_k Cov(g_k, g_{k+lag})

(covariances over drives at fixed frames) tells which failure makes ``tr(H^-1 G)/p`` exceed 1:
the same-update term ``tr(H^-1 C(0))/p`` (each update's innovations scatter otherwise than its S
says, along the calibration's directions) or the cross terms (scores correlated across updates:
an error the filter does not model persists from one update to the next). The lag of the cross
terms says how long it persists: 1-2 frames is the overlap of the triplets, tens to hundreds of
frames a slow error such as a bias or a drifting pose.

Method as studies/objective/information_equality.py (the same fresh drives, imposed decisions,
central differences in the flat-city variables, dy, dz at the truth), but per update frame:
``g_k`` (D, N, 8) from the per-frame joint NLL and H (D, 8, 8) the drive's Hessian, fx and fy
apart (the mean score's t per variable); the split is taken in the 7 free variables (f = fx = fy).
Results: studies/objective/README.md, "where the excess comes from".

    python studies/objective/score_lags.py [--seeds 0 1 2 3 4] [--drives 10] [--sim JSON] [--filter JSON] [--adjusted] [--save F.npz | --load F.npz]

About 2.6 s of CPU per drive on one thread (129 calibrations of a 78 s drive); 100 drives ~4.5 min.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))
sys.path.insert(0, str(ROOT / "studies" / "identifiability"))

from information_equality import A7, STEP, VARS, tilt_line, typical
from minimiser_scatter import derivatives, design
from objective_bias import DRIVE, FRESH_SEED0

from avio.filter.batch import set_threads
from avio.objectives import joint_update_nll, scored_frames, update_adjustment
from avio.sequence import ImuNoise
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import Synthetic

#: lag bands (frames; a triplet spans 2 frame steps, an update every frame)
BANDS = ((0, 0), (1, 2), (3, 10), (11, 50), (51, 200), (201, 10**9))


def frame_nll(res, scored: np.ndarray, adjusted: bool = False) -> np.ndarray:
    """(n, N) joint NLL of each update frame (Eq. 55a's used-residual term; the unused slots' cap is
    the same for every calibration under imposed decisions), 0 where not scored; adjusted: plus
    ``1/2 tr(S^-1 R)`` (Eq. 55b, ``innovation_nll_adjusted``)."""
    frame = joint_update_nll(res)
    if adjusted:
        frame = frame + update_adjustment(res)
    return np.where(scored[None], frame, 0.0)


def sim_config(sim: dict | None) -> SimConfig:
    """The fresh drives' preset with SimConfig overrides; an ``imu_noise`` given as a dict of
    ImuNoise fields (the rest at their defaults; the filter's process noise follows it)."""
    sim = dict(sim or {})
    if isinstance(sim.get("imu_noise"), dict):
        sim["imu_noise"] = ImuNoise(**sim["imu_noise"])
    for key in ("accel_bias_mps2", "gyro_bias_radps"):
        if sim.get(key) is not None:
            sim[key] = tuple(sim[key])
    return SimConfig.paper_540m(**sim)


def measure(seeds, n_drives: int, sim: dict | None = None, filter_options: dict | None = None,
            adjusted: bool = False) -> dict:
    """Per drive the per-frame gradients (D, N, 8) and the drive's Hessian (D, 8, 8) of the joint
    NLL at the truth in the flat city's variables (VARS, fx and fy apart; filter_options: FilterConfig overrides
    besides the imposed decisions, e.g. a pixel noise that matches the drives')."""
    config = sim_config(sim)
    h = np.array([STEP[v] for v in VARS])
    gs, Hs, skipped = [], [], 0
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local",
                            filter={"outlier_decisions": "reference_all", **(filter_options or {})})
        cols = [problem.space.names.index(v) for v in VARS]
        X = np.repeat(problem.truth[None], len(design(len(VARS), h)), axis=0)
        X[:, cols] += design(len(VARS), h)
        batch = problem.calibration_space.decode(X)
        camera = problem.sequence.truth_calibration
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=camera)
            res = problem.run_filter(batch, drive)
            if res.diverged.any():
                skipped += 1
                continue
            nll = frame_nll(res, scored_frames(drive), adjusted)  # (n, N)
            g, _ = derivatives(nll, h)  # (8, N)
            _, H = derivatives(nll.sum(axis=1), h)  # (8, 8)
            gs.append(g.T)
            Hs.append(H)
    N = min(len(g) for g in gs)
    return {"g": np.array([g[:N] for g in gs]), "H": np.array(Hs), "skipped": skipped}


def band_term(c: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """(p, p) sum over lags lo..hi of C(lag) + C(lag)^T (lag 0 once), C(lag) = sum_k Cov(g_k, g_{k+lag})
    over drives; c (D, N, p) the scores centred per frame. The lags' sum is a window sum
    (cumulative sums), so no (N, N) cross-product is formed."""
    D, N, _ = c.shape
    cum = np.concatenate([np.zeros_like(c[:, :1]), np.cumsum(c, axis=1)], axis=1)  # (D, N + 1, p)
    k = np.arange(N)
    a, b = np.minimum(k + lo, N), np.minimum(k + hi + 1, N)
    window = cum[:, b] - cum[:, a]  # (D, N, p): sum of c_l over l in [k + lo, k + hi]
    C = np.einsum("dki,dkj->ij", c, window) / (D - 1)
    return C + C.T if lo > 0 else C + C.T - np.einsum("dki,dkj->ij", c, c) / (D - 1)


def split(g: np.ndarray, H: np.ndarray) -> dict:
    """tr(H^-1 C_band)/p per lag band, their sum (= tr(H^-1 G)/p), and the same per variable
    (C_band_ii / H_ii)."""
    Hm = 0.5 * (H.mean(axis=0) + H.mean(axis=0).T)
    c = g - g.mean(axis=0)
    p = g.shape[2]
    out = {"band": [], "trace": [], "diag": []}
    for lo, hi in BANDS:
        Cb = band_term(c, lo, min(hi, g.shape[1] - 1))
        out["band"].append((lo, hi))
        out["trace"].append(float(np.trace(np.linalg.solve(Hm, Cb)) / p))
        out["diag"].append(np.diag(Cb) / np.diag(Hm))
    G = np.cov(g.sum(axis=1).T)
    out["total"] = float(np.trace(np.linalg.solve(Hm, G)) / p)
    out["total_diag"] = np.diag(G) / np.diag(Hm)
    return out


def bootstrap(g: np.ndarray, H: np.ndarray, rng, n: int = 500) -> np.ndarray:
    """(len(BANDS) + 1, 2) 95 % percentile intervals of the bands' traces and the total, drives
    resampled with replacement."""
    D = len(g)
    values = []
    for _ in range(n):
        pick = rng.integers(0, D, D)
        s = split(g[pick], H[pick])
        values.append([*s["trace"], s["total"]])
    return np.quantile(np.array(values), [0.025, 0.975], axis=0).T


def free7(g8: np.ndarray, H8: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The scores (D, N, 7) and Hessians (D, 7, 7) in the 7 free variables (f = fx = fy); files
    saved before fx and fy were kept apart hold them already."""
    if g8.shape[-1] == 7:
        return g8, H8
    return g8 @ A7, np.einsum("ai,dab,bj->dij", A7, H8, A7)


def report(data: dict, rng) -> list[str]:
    """The table: per lag band its share of tr(H^-1 G)/7 over the typical drives, with a bootstrap
    interval, and per variable; then the mean drive score's t at the truth (fx, fy apart)."""
    g8 = data["g"]
    g, H = free7(data["g"], data["H"])
    keep = typical(H)
    g, H = g[keep], H[keep]
    s = split(g, H)
    ci = bootstrap(g, H, rng)
    names = ("f",) + VARS[2:]
    lines = [f"typical drives: {keep.sum()} of {len(keep)}; frames {g.shape[1]}",
             "| lags (frames) | tr(H⁻¹C)/7 [95 %] | C_ii/H_ii (" + ", ".join(names) + ") |", "|---|---|---|"]
    for (lo, hi), t, d, (a, b) in zip(s["band"], s["trace"], s["diag"], ci):
        label = f"{lo}" if lo == hi else (f"{lo}–{hi}" if hi < 10**9 else f"≥ {lo}")
        lines.append(f"| {label} | {t:.2f} [{a:.2f}–{b:.2f}] | " + ", ".join(f"{v:.2f}" for v in d) + " |")
    a, b = ci[-1]
    lines.append(f"| all (= tr(H⁻¹G)/7) | {s['total']:.2f} [{a:.2f}–{b:.2f}] | "
                 + ", ".join(f"{v:.2f}" for v in s["total_diag"]) + " |")
    Hm = H.mean(axis=0)
    Hinv = np.linalg.inv(0.5 * (Hm + Hm.T))
    G = np.cov(g.sum(axis=1).T)
    lines.append("one drive's minimiser scatter (sandwich sqrt diag H⁻¹GH⁻¹; px, deg, m): "
                 + ", ".join(f"{n} {v:.3g}" for n, v in zip(names, np.sqrt(np.diag(Hinv @ G @ Hinv)))))
    tnames = VARS if g8.shape[-1] == 8 else names
    lines.append(tilt_line(g8.sum(axis=1), keep, tnames))  # every drive's score, for the tilt
    return lines


def paired(a: dict, b: dict, rng, n: int = 500) -> list[str]:
    """Two saves of the same drives (two likelihoods or filters): per variable each one's G_ii/H_ii
    over the drives typical in both, and b's over a's with a 95 % percentile interval, the drives
    resampled in pairs."""
    (ga, Ha), (gb, Hb) = free7(a["g"], a["H"]), free7(b["g"], b["H"])
    if ga.shape != gb.shape:
        raise SystemExit(f"score_lags: --paired needs saves of the same drives, got {ga.shape} and {gb.shape}")
    both = np.flatnonzero(typical(Ha) & typical(Hb))
    da, db = split(ga[both], Ha[both])["total_diag"], split(gb[both], Hb[both])["total_diag"]
    ratios = []
    for _ in range(n):
        pick = rng.choice(both, len(both))
        ratios.append(split(gb[pick], Hb[pick])["total_diag"] / split(ga[pick], Ha[pick])["total_diag"])
    lo, hi = np.quantile(np.array(ratios), [0.025, 0.975], axis=0)
    names = ("f",) + VARS[2:]
    return [f"drives typical in both: {len(both)} of {len(ga)}",
            "| variable | G_ii/H_ii, first | second | second ÷ first [95 %] |", "|---|---|---|---|",
            *(f"| {v} | {x:.2f} | {y:.2f} | {y / x:.2f} [{p:.2f}–{q:.2f}] |"
              for v, x, y, p, q in zip(names, da, db, lo, hi))]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras (data seeds)")
    parser.add_argument("--drives", type=int, default=10, help="fresh drives per camera")
    parser.add_argument("--sim", type=json.loads, default=None,
                        help='SimConfig overrides of the fresh drives as JSON, e.g. \'{"imu_noise_on": false}\' or \'{"imu_noise": {"gyro_noise": 1e-9}}\'')
    parser.add_argument("--filter", type=json.loads, default=None,
                        help='FilterConfig overrides as JSON, e.g. \'{"pixel_sigma_px": 0.35}\'')
    parser.add_argument("--adjusted", action="store_true",
                        help="the adjusted joint likelihood (innovation_nll_adjusted, Eq. 55b)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--save", type=Path, help="write the per-frame gradients and Hessians (.npz)")
    parser.add_argument("--load", type=Path, help="report from a --save file instead of measuring")
    parser.add_argument("--paired", type=Path, nargs=2, metavar=("A", "B"),
                        help="compare two --save files of the same drives, variable by variable")
    args = parser.parse_args(argv)
    if args.paired:
        a, b = (np.load(f) for f in args.paired)
        print(f"{args.paired[0]} (first) against {args.paired[1]} (second)")
        print("\n".join(paired(a, b, np.random.default_rng(0))))
        return
    set_threads(args.threads)
    start = time.process_time()
    if args.load:
        saved = np.load(args.load)
        data = {"g": saved["g"], "H": saved["H"], "skipped": int(saved["skipped"])}
    else:
        data = measure(args.seeds, args.drives, args.sim, args.filter, args.adjusted)
    if args.save:
        np.savez(args.save, **data)
    print(f"{DRIVE}, {'adjusted ' if args.adjusted else ''}sim {args.sim or 'default'}, filter {args.filter or 'default'}: cameras {args.seeds}, {args.drives} fresh drives each "
          f"({data['skipped']} skipped: a filter diverged), imposed decisions, {time.process_time() - start:.0f} s CPU")
    print("\n".join(report(data, np.random.default_rng(0))))


if __name__ == "__main__":
    main()
