"""Is each innovation likelihood a likelihood at the truth? Its information-matrix equality and its
mean gradient on fresh drives (issue 33).

For a correctly specified log-likelihood l(x) of one drive, at the true x: the mean gradient is
zero and the gradients' covariance G equals the mean Hessian H (the information-matrix
equality), so ``tr(H^-1 G) / p = 1`` and every eigenvalue of ``H^-1 G`` is 1. A composite
likelihood (the per-feature ``innovation_nll``) or a misspecified one breaks the equality; a
term of the model that is wrong at the truth tilts the mean gradient.

Method: on fresh drives of the identifiability study's cameras (data seed s, drives
``(s, 100 + i)`` of the ``paper_540m`` preset, as studies/objective/objective_bias.py), imposed
decisions (``outlier_decisions: reference_all``: the same features for every calibration), one
batch per drive holds the truth and a central-difference design in the flat-city variables
fx, fy, cx, cy, rx, ry, rz, dx (dy, dz at the truth; studies/identifiability/minimiser_scatter.py's
``design``). Per drive and objective, the gradient and Hessian of the drive's *total* NLL (nats:
the per-residual objective times its calibration-free slot count). Reported per objective:

- the mean gradient's t-statistic along each of the 8 variables (fy included), over all drives and
  over the typical ones, and the signed-rank test's p (:func:`tilt`);
- for the study's 7 free variables (fy = fx: the common focal length f; ``A`` maps them into
  the 8), ``tr(H^-1 G) / 7`` with a bootstrap 95 % interval over the drives, and the largest
  eigenvalue of ``H^-1 G``; the same over the typical drives (a few drives' curvatures are 10-50x
  the median or negative, and swing the mean Hessian's weak directions), with the per-variable
  ratios ``G_ii / H_ii`` (1 where the equality holds).

    python studies/objective/information_equality.py [--seeds 0 1 2 3 4] [--drives 10] [--sim JSON] [--filter JSON] [--all-ten] [--noise-draws R] [--save F.npz] [--load F.npz]
    python studies/objective/information_equality.py --profile SEED DRIVE VAR [--filter JSON]

``--profile`` follows one drive (camera SEED, fresh drive DRIVE) along one variable, from -1 to
+1 step: each frame's joint term (``½(r^T S^-1 r + log det S)``, nats) against the truth's, for
the frames that move most (an outlying drive's score: where the likelihood stops being smooth).

About 2 s of CPU per drive (129 calibrations of a 78 s drive) on one thread: 112 s for the default 50 drives on
the 2-core AVX2 machine (2026-12-06).
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

from minimiser_scatter import derivatives, design
from objective_bias import DRIVE, FRESH_SEED0

from avio.filter.batch import set_threads
from avio.objectives import innovation_nll, innovation_nll_joint, scored_frames, unused_feature_nll
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import NOISE_WORD, Synthetic

VARS = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx")
#: the excited rig (``--rig full3d_540m``): every variable, all ten free (issue 33)
VARS10 = (*VARS, "dy", "dz")
#: central-difference steps (px, deg, m): with imposed decisions both likelihoods are smooth, so
#: half minimiser_scatter.py's steps (chosen for the roughness of the filters' own decisions)
STEP = {"fx": 1.5, "fy": 1.5, "cx": 1.5, "cy": 1.5, "rx": 0.15, "ry": 0.15, "rz": 0.15, "dx": 0.015, "dy": 0.015,
        "dz": 0.015}
OBJECTIVES = ("innovation_nll", "innovation_nll_joint")
#: the 7 free variables of the flat-city rows: f = fx = fy, then cx, cy, rx, ry, rz, dx
A7 = np.zeros((8, 7))
A7[0, 0] = A7[1, 0] = 1.0
A7[2:, 1:] = np.eye(6)


def drive_totals(problem: Synthetic, batch, drive) -> dict[str, np.ndarray] | None:
    """(n,) total NLL (nats) of each objective on one drive, or None when a filter diverged."""
    res = problem.run_filter(batch, drive)
    if res.diverged.any():
        return None
    scored = scored_frames(drive)
    slots = np.where(scored, res.nll_slots, 0).sum(axis=1).astype(float)
    c = problem.filter_config
    per = {"innovation_nll": innovation_nll([res], 1.0, [scored])[0],
           "innovation_nll_joint": innovation_nll_joint([res], 1.0, unused_feature_nll(c.pixel_sigma_px,
                                                                                      c.chi2_threshold), [scored])}
    return {k: v * slots for k, v in per.items()}


def rig_vars(rig: str, all_ten: bool = False) -> tuple[str, ...]:
    """The variables measured on a rig's drives: the flat city's 8 (dy, dz weakly determined there;
    with ``all_ten`` they are measured too), or all 10."""
    return VARS if rig == DRIVE and not all_ten else VARS10


def free_map(rig: str, measured: tuple[str, ...]) -> np.ndarray:
    """(len(measured), p) the rig's free variables into the measured ones: the flat city's 7 of its
    rows (:data:`A7`; dy, dz, where measured, held at the truth), the excited rig's all."""
    if rig != DRIVE:
        return np.eye(len(measured))
    return np.vstack([A7, np.zeros((len(measured) - len(VARS), A7.shape[1]))])


def reference_all_problem(seed: int, rig: str = DRIVE, filter_options: dict | None = None) -> Synthetic:
    """Camera ``seed``'s problem on the rig in the local space, with imposed reference_all decisions
    (filter_options: further FilterConfig overrides)."""
    return Synthetic(drives=[rig], holdout=None, data_seed=seed, space="local",
                     filter={"outlier_decisions": "reference_all", **(filter_options or {})})


def fresh_drive(problem: Synthetic, rig: str, seed: int, i: int, sim: dict | None = None, noise_draw: int = 0):
    """Fresh drive i of camera ``seed`` (``(seed, FRESH_SEED0 + i)``; sim: SimConfig overrides); with
    ``noise_draw`` r > 0 the same trajectory and world with another measurement-noise realisation (as
    bench/problems/synthetic.py's noise realisations)."""
    return simulate(getattr(SimConfig, rig)(**(sim or {})), (seed, FRESH_SEED0 + i),
                    true_calibration=problem.sequence.truth_calibration,
                    noise_seed=None if noise_draw == 0 else (seed, FRESH_SEED0 + i, NOISE_WORD, noise_draw))


def measure(seeds, n_drives: int, sim: dict | None = None, rig: str = DRIVE, filter_options: dict | None = None,
            all_ten: bool = False, noise_draws: int = 1) -> dict:
    """Per objective (D, p) gradients and (D, p, p) Hessians at the truth, per unit of
    ``rig_vars(rig, all_ten)`` (sim: SimConfig overrides of the fresh drives; rig: their preset; filter_options:
    FilterConfig overrides over the imposed reference_all decisions). The entries of a subset of the
    variables are those a design in that subset gives (the same calibrations, and a batch gives the
    bits of single runs). With ``noise_draws`` R > 1 each trajectory is measured under R noise
    realisations (``out["trajectory"]`` names each entry's trajectory): the mean of its Hessians
    estimates that trajectory's Fisher information (studies/identifiability/cramer_rao.py --sets)."""
    out = {k: {"g": [], "H": []} for k in OBJECTIVES}
    trajectory = []
    skipped = 0
    names = rig_vars(rig, all_ten)
    h = np.array([STEP[v] for v in names])
    for seed in seeds:
        problem = reference_all_problem(seed, rig, filter_options)
        cols = [problem.space.names.index(v) for v in names]
        X = np.repeat(problem.truth[None], len(design(len(names), h)), axis=0)
        X[:, cols] += design(len(names), h)
        batch = problem.calibration_space.decode(X)
        for i in range(n_drives):
            for r in range(noise_draws):
                totals = drive_totals(problem, batch, fresh_drive(problem, rig, seed, i, sim, r))
                if totals is None:
                    skipped += 1
                    continue
                for k in OBJECTIVES:
                    g, H = derivatives(totals[k], h)
                    out[k]["g"].append(g)
                    out[k]["H"].append(H)
                trajectory.append(1000 * seed + i)
    for k in OBJECTIVES:
        out[k] = {q: np.array(v) for q, v in out[k].items()}
    out["skipped"] = skipped
    out["trajectory"] = np.array(trajectory, dtype=np.int64)
    return out


def equality(g: np.ndarray, H: np.ndarray) -> tuple[float, float]:
    """``tr(H^-1 G) / p`` and the largest eigenvalue of ``H^-1 G`` (G the gradients' covariance,
    H the mean Hessian; g (D, p), H (D, p, p))."""
    Hm = 0.5 * (H.mean(axis=0) + H.mean(axis=0).T)
    G = np.cov(g.T)
    M = np.linalg.solve(Hm, G)
    return float(np.trace(M) / g.shape[1]), float(np.max(np.linalg.eigvals(M).real))


def bootstrap(g: np.ndarray, H: np.ndarray, rng, n: int = 2000) -> tuple[float, float]:
    """95 % percentile interval of ``tr(H^-1 G) / p`` over drives resampled with replacement."""
    D = len(g)
    values = []
    for _ in range(n):
        pick = rng.integers(0, D, D)
        values.append(equality(g[pick], H[pick])[0])
    return float(np.quantile(values, 0.025)), float(np.quantile(values, 0.975))


def tilt(g: np.ndarray, keep: np.ndarray) -> dict[str, np.ndarray]:
    """The mean drive score's tests at the truth, per variable (g (D, p) the drives' scores, keep
    (D,) the typical drives): ``t_all`` the t-statistic over every drive, ``t_typical`` over the
    typical ones, ``p_wilcoxon`` the signed-rank test's two-sided p over every drive. A few rough
    drives' scores are 10-100x the others' and inflate the SE, so ``t_all`` alone can hide a
    tilt every typical drive shows (measured: the corrected likelihood's fy, docs/decisions.md);
    the signed-rank test is not moved by their size."""
    from scipy.stats import wilcoxon  # the study's only scipy.stats need

    def t(x):
        return x.mean(axis=0) / (x.std(axis=0, ddof=1) / np.sqrt(len(x)))

    return {"t_all": t(g), "t_typical": t(g[keep]), "p_wilcoxon": wilcoxon(g, axis=0).pvalue}


def tilt_line(g: np.ndarray, keep: np.ndarray, names) -> str:
    """One line: per variable the t over all drives, over the typical ones, and the signed-rank p."""
    s = tilt(g, keep)
    return "mean drive score at the truth, t all / t typical / signed-rank p: " + "; ".join(
        f"{n} {a:+.1f} / {b:+.1f} / {c:.2g}" for n, a, b, c in zip(names, s["t_all"], s["t_typical"], s["p_wilcoxon"]))


def typical(H: np.ndarray, k: float = 5.0) -> np.ndarray:
    """(D,) bool: drives whose Hessian diagonal lies within k scaled MADs of the drives' median on
    every variable (a few drives have curvatures 10-50x the median, or negative ones: the
    likelihood is not quadratic at the steps' scale there)."""
    diag = np.einsum("dii->di", H)
    med = np.median(diag, axis=0)
    mad = 1.4826 * np.median(np.abs(diag - med), axis=0)
    return np.all(np.abs(diag - med) <= k * mad, axis=1)


def profile(seed: int, i: int, var: str, rig: str = DRIVE, filter_options: dict | None = None,
            n: int = 13, worst: int = 3) -> list[str]:
    """Lines: one drive's total and its ``worst`` frames' joint terms (nats, against the truth's) at
    n steps of ``var`` over ``[-STEP, +STEP]`` (see the module docstring)."""
    problem = reference_all_problem(seed, rig, filter_options)
    steps = np.linspace(-STEP[var], STEP[var], n)
    X = np.repeat(problem.truth[None], n, axis=0)
    X[:, problem.space.names.index(var)] += steps
    res = problem.run_filter(problem.calibration_space.decode(X), fresh_drive(problem, rig, seed, i))
    terms = 0.5 * (res.nis + res.log_det_S)  # (n, N) each frame's joint term without the constant
    terms = terms - terms[n // 2]
    jump = np.abs(np.diff(terms, axis=0)).max(axis=0)
    lines = [f"{rig}, camera {seed}, fresh drive {i}, filter {filter_options or 'default'}: {var} + "
             + ", ".join(f"{v:+.3g}" for v in steps),
             "total: " + ", ".join(f"{v:.3g}" for v in terms.sum(axis=1))]
    for frame in np.argsort(jump)[::-1][:worst]:
        lines.append(f"frame {frame} ({res.dof[n // 2, frame]} residuals): " + ", ".join(f"{v:.3g}" for v in terms[:, frame]))
    return lines


def report(data: dict, rng, rig: str = DRIVE, measured: tuple[str, ...] | None = None) -> list[str]:
    """The table's lines: per objective the equality in the rig's free variables (flat city: the 7
    of its rows; full3d: all 10) over all drives and over the typical ones (:func:`typical`), with
    the per-variable ratios G_ii / H_ii there, and the mean-gradient t-statistics (all drives;
    measured: the variables of the data, ``rig_vars(rig)`` by default)."""
    measured = measured or rig_vars(rig)
    A = free_map(rig, measured)
    names = ("f",) + VARS[2:] if rig == DRIVE else measured
    p = A.shape[1]
    lines = [f"| objective | drives | tr(H⁻¹G)/{p} [95 % bootstrap] | largest eigenvalue | typical drives: tr(H⁻¹G)/{p} "
             "[95 %] | G_ii/H_ii there (" + ", ".join(names) + ") | " + " | ".join(f"t({v})" for v in measured) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(measured)]
    for k in OBJECTIVES:
        g, H = data[k]["g"], data[k]["H"]
        g7, H7 = g @ A, np.einsum("ia,dij,jb->dab", A, H, A)
        ratio, top = equality(g7, H7)
        lo, hi = bootstrap(g7, H7, rng)
        keep = typical(H7)
        r_t = equality(g7[keep], H7[keep])[0]
        lo_t, hi_t = bootstrap(g7[keep], H7[keep], rng)
        diag = np.diag(np.cov(g7[keep].T)) / np.diag(H7[keep].mean(axis=0))
        t = tilt(g, keep)
        lines.append(f"| `{k}` | {len(g)} | {ratio:.2f} [{lo:.2f}–{hi:.2f}] | {top:.2f} | "
                     f"{r_t:.2f} [{lo_t:.2f}–{hi_t:.2f}] ({keep.sum()} drives) | "
                     + ", ".join(f"{v:.1f}" for v in diag) + " | "
                     + " | ".join(f"{a:+.1f} / {b:+.1f} / {c:.2g}" for a, b, c in zip(t["t_all"], t["t_typical"], t["p_wilcoxon"]))
                     + " |")
    lines.append("(t(v): the mean score's t over all drives / over the typical drives / the signed-rank p over all)")
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras (data seeds)")
    parser.add_argument("--drives", type=int, default=10, help="fresh drives per camera")
    parser.add_argument("--sim", type=json.loads, default=None,
                        help='SimConfig overrides of the fresh drives as JSON, e.g. \'{"pixel_noise_per_triplet": true}\'')
    parser.add_argument("--filter", type=json.loads, default=None,
                        help='FilterConfig overrides as JSON, e.g. \'{"jacobian_pixels": "corrected"}\'')
    parser.add_argument("--rig", default=DRIVE, choices=[DRIVE, "full3d_540m"],
                        help="the drives' preset: the flat city (8 variables measured, 7 free) or the excited rig (all 10)")
    parser.add_argument("--all-ten", action="store_true",
                        help="on the flat city, measure dy and dz too (the 7 free variables' figures are unchanged; "
                             "studies/identifiability/cramer_rao.py --frozen needs them)")
    parser.add_argument("--noise-draws", type=int, default=1, metavar="R",
                        help="measure each drive's trajectory under R noise realisations (for cramer_rao.py --sets: "
                             "each trajectory's information as the mean of its Hessians)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--save", type=Path, help="write the gradients and Hessians (.npz)")
    parser.add_argument("--load", type=Path, help="report from a --save file instead of measuring")
    parser.add_argument("--profile", nargs=3, metavar=("SEED", "DRIVE", "VAR"),
                        help="one drive's frame terms along one variable instead (module docstring)")
    args = parser.parse_args(argv)
    set_threads(args.threads)
    if args.profile:
        seed, i, var = args.profile
        if var not in rig_vars(args.rig):
            parser.error(f"--profile: VAR must be one of {', '.join(rig_vars(args.rig))}, not {var!r}")
        print("\n".join(profile(int(seed), int(i), var, args.rig, args.filter)))
        return
    start = time.process_time()
    if args.load:
        saved = np.load(args.load)
        data = {k: {"g": saved[f"{k}_g"], "H": saved[f"{k}_H"]} for k in OBJECTIVES}
        data["skipped"] = int(saved["skipped"])
        args.rig = str(saved["rig"]) if "rig" in saved else DRIVE  # files saved before --rig: the flat city
        args.filter = json.loads(str(saved["filter"])) if "filter" in saved else None
        measured = tuple(str(v) for v in saved["vars"]) if "vars" in saved else rig_vars(args.rig)
    else:
        data = measure(args.seeds, args.drives, args.sim, args.rig, args.filter, args.all_ten, args.noise_draws)
        measured = rig_vars(args.rig, args.all_ten)
    if args.save:
        np.savez(args.save, skipped=data["skipped"], rig=args.rig, filter=json.dumps(args.filter or {}), vars=np.array(measured),
                 **({"trajectory": data["trajectory"]} if "trajectory" in data else {}),
                 **{f"{k}_{q}": data[k][q] for k in OBJECTIVES for q in "gH"})
    print(f"{args.rig}, sim {args.sim or 'default'}, filter {args.filter or 'default'}: cameras {args.seeds}, {args.drives} fresh drives each ({data['skipped']} skipped: a filter diverged), "
          f"imposed decisions (reference_all), {time.process_time() - start:.0f} s CPU")
    print("\n".join(report(data, np.random.default_rng(0), args.rig, measured)))


if __name__ == "__main__":
    main()
