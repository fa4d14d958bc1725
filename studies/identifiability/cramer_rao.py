"""What can K calibration drives tell about the calibration at best? The Cramér–Rao bound from the
Fisher information of the joint innovation likelihood (issue 33).

The Fisher information of the calibration on one drive is the expected Hessian of the drive's
negative log-likelihood at the truth, ``I = E[d^2 l / dx^2]``, measured as the mean over fresh
drives of the numerical Hessian of the joint likelihood (``innovation_nll_joint``, total nats per
drive; studies/objective/information_equality.py measures and saves it). K independent drives
carry ``K I``; any unbiased calibration from them has covariance at least ``(K A^T I A)^-1`` in the
free variables ``y`` of a configuration (``x = A y + c``, frozen or tied variables in A, c). Its
square roots are the bound on each variable; drawing ``y ~ N(y_t, (K A^T I A)^-1)`` and taking the
reported errors (avio.calibration.calibration_errors: rotation deg, focal px, principal point
px, lever arm cm) of the draws gives the bound on each error's median — the errors of an
efficient estimator. A configuration's *efficiency* on a variable is the bound divided by the
error achieved (1: as good as the data allow).

This is a bound only as far as the joint likelihood is the data's likelihood
(studies/objective/information_equality.py tests that: ``tr(H^-1 G)/p = 1`` at the truth).
studies/identifiability/minimiser_scatter.py predicts something else: where one objective's
minimiser falls (an M-estimator sandwich ``H^-1 G H^-1``), which may be far above this bound.

    python studies/identifiability/cramer_rao.py --load IE.npz [--K 1 4 16] [--seeds 0 1 2 3 4] [--typical]
    python studies/identifiability/cramer_rao.py --load IE10.npz --frozen dy dz
    python studies/identifiability/cramer_rao.py --load IE.npz --sets 400 [--K 1 4 16]

``--frozen`` says instead how far variables held at the reference, as the study's configurations hold
them, move the likelihood's limit (:func:`frozen_errors`; IE10.npz: ``information_equality.py
--all-ten``, dy and dz measured on the flat city too). The study's summary gives every configuration's
bound and efficiency (:func:`configuration_bound`). ``--sets`` checks the mean Hessian's bound against
the bound of random K-drive sets, each from its own drives' summed curvature (:func:`set_bounds`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

#: the reported errors (avio.calibration.calibration_errors)
ERRORS = ("rotation_error_deg", "focal_error_px", "principal_point_error_px", "translation_error_cm")


def fisher_information(hessians: np.ndarray) -> np.ndarray:
    """(p, p) Fisher information of one drive: the symmetrised mean of per-drive Hessians (D, p, p)
    of the negative log-likelihood at the truth (nats per unit^2)."""
    H = np.asarray(hessians, float).mean(axis=0)
    return 0.5 * (H + H.T)


def outer_product_information(gradients: np.ndarray) -> np.ndarray:
    """(p, p) Fisher information of one drive estimated by the outer product of the per-drive score
    vectors (D, p) at the truth (the BHHH estimate; equal to the mean Hessian's where the
    information-matrix equality holds, and positive semi-definite where the mean Hessian of few
    drives is not)."""
    g = np.asarray(gradients, float)
    return g.T @ g / len(g)


def bound_covariance(information: np.ndarray, K: int, A: np.ndarray | None = None) -> np.ndarray:
    """(r, r) Cramér–Rao covariance bound ``(K A^T I A)^-1`` of the free variables after K drives
    (A (p, r): free variables into the measured ones; None: all free). Raises LinAlgError when a
    free direction carries no information."""
    A = np.eye(len(information)) if A is None else A
    info = K * A.T @ information @ A
    if np.linalg.eigvalsh(info)[0] <= 0:
        raise np.linalg.LinAlgError("a free direction has no positive information: not identifiable")
    return np.linalg.inv(info)


def error_bounds(cov: np.ndarray, to_calibration, truth, rng, draws: int = 4000) -> dict[str, float]:
    """Median of each reported error over draws ``dy ~ N(0, cov)`` of an efficient estimator
    (to_calibration(dy (draws, r)) -> Calibration batch; truth: Calibration batch of 1)."""
    from avio.calibration import calibration_errors

    dy = rng.multivariate_normal(np.zeros(len(cov)), cov, size=draws, method="eigh")
    errs = calibration_errors(to_calibration(dy), truth)
    return {k: float(np.median(errs[k])) for k in ERRORS}


def median_error_bounds(cov: np.ndarray, A: np.ndarray, measured: tuple[str, ...], rig: str, seeds, rng) -> dict[str, float]:
    """Each reported error's bound (:func:`error_bounds`), the median over cameras ``seeds`` of ``rig``
    (cov (r, r) of the free variables, A (len(measured), r) maps them into the measured ones)."""
    from bench.problems.synthetic import Synthetic

    per = {k: [] for k in ERRORS}
    for seed in seeds:
        problem = Synthetic(drives=[rig], holdout=None, data_seed=seed, space="local")
        cols = [problem.space.names.index(v) for v in measured]

        def decode(dy, problem=problem, cols=cols):
            X = np.repeat(problem.truth[None], len(dy), axis=0)
            X[:, cols] += dy @ A.T
            return problem.calibration_space.decode(X)

        for k, v in error_bounds(cov, decode, problem.sequence.truth_calibration, rng).items():
            per[k].append(v)
    return {k: float(np.median(v)) for k, v in per.items()}


#: the variables each reported error measures: its bound applies where all of them are free
ERROR_VARIABLES = {"rotation_error_deg": ("rx", "ry", "rz"), "focal_error_px": ("fx", "fy"),
                   "principal_point_error_px": ("cx", "cy"), "translation_error_cm": ("dx", "dy", "dz")}
#: the local space's variables (bench/problems/calibration_space.py), td last where it is free
SPACE_VARIABLES = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz")


def saved_rig(saved) -> tuple[str, tuple[str, ...]]:
    """(rig, measured variables) of an information_equality.py --save file (files saved before --rig:
    the flat city, its 8 variables)."""
    from information_equality import VARS
    from objective_bias import DRIVE

    rig = str(saved["rig"]) if "rig" in saved else DRIVE
    return rig, (tuple(str(v) for v in saved["vars"]) if "vars" in saved else VARS)


def configuration_map(measured: tuple[str, ...], fixed=(), tie_focal: bool = False,
                      with_time_offset: bool = False) -> tuple[np.ndarray, list[str]] | None:
    """(A, free): a configuration's free variables (the local space's ten less ``fixed``, fy tied to
    fx with ``tie_focal``, the time offset with ``with_time_offset``) and A (len(measured), len(free))
    mapping them into the measured ones; None where a free variable was not measured."""
    free = [v for v in SPACE_VARIABLES + (("td",) if with_time_offset else ()) if v not in fixed
            and not (tie_focal and v == "fy")]
    if any(v not in measured for v in free):
        return None
    A = np.zeros((len(measured), len(free)))
    for j, v in enumerate(free):
        A[measured.index(v), j] = 1.0
        if tie_focal and v == "fx":
            A[measured.index("fy"), j] = 1.0
    return A, free


def frozen_errors(saved, fixed, tie_focal: bool, seeds) -> list[dict[str, float]]:
    """Per camera of ``seeds``: the reported errors at the joint likelihood's limit when ``fixed`` are held
    at the reference, as the study's runs hold them: the minimum of the quadratic model with the mean
    Hessian of ``saved`` (all ten variables measured) and no gradient, i.e. minimiser_scatter.predict with
    zero scores (the shift ``-(A^T H A)^-1 A^T H (c - x_t)`` of the configuration's subspace ``A y + c``);
    the number of drives cancels, so it is the limit of any number of drives, a bias and not a scatter."""
    from minimiser_scatter import predict

    rig, measured = saved_rig(saved)
    if tuple(measured) != SPACE_VARIABLES:
        raise ValueError(f"the file measured {', '.join(measured)}: --frozen needs all ten variables "
                         "(information_equality.py --all-ten measures dy, dz on the flat city)")
    H = saved["innovation_nll_joint_H"]
    out = predict(np.zeros((len(H), len(measured))), H, 1, {"frozen": (tie_focal, tuple(fixed))}, seeds, 1,
                  np.random.default_rng(0))["frozen"]
    return [{k: float(out[k][i, 0]) for k in ERRORS} for i in range(len(seeds))]


def configuration_bound(saved, K: int, fixed=(), tie_focal: bool = False, with_time_offset: bool = False,
                        seeds=(0, 1, 2, 3, 4), rng=None) -> dict | None:
    """The bound on each reported error of a study configuration: K drives of the rig of ``saved``
    (an information_equality.py --save file, loaded), its free variables (the local space's ten
    less ``fixed``, fy tied to fx with ``tie_focal``, the time offset with ``with_time_offset``).
    None where a free variable is not among the file's measured ones (no bound from it). The
    information: the mean Hessian where it is positive definite in the free variables, else the
    scores' outer product (the excited rig's mean Hessian is indefinite, studies/identifiability/README.md).
    Returns {"information": "hessian" | "opg", error: median bound, or None where the error's variables are
    not all free (a fixed variable's error is the fixed value's, not an estimate's)}."""
    rig, measured = saved_rig(saved)
    mapped = configuration_map(measured, fixed, tie_focal, with_time_offset)
    if mapped is None:
        return None
    A, free = mapped
    H, g = saved["innovation_nll_joint_H"], saved["innovation_nll_joint_g"]
    info, kind = fisher_information(H), "hessian"
    if np.linalg.eigvalsh(A.T @ info @ A)[0] <= 0:
        info, kind = outer_product_information(g), "opg"
    return {"information": kind, **free_error_bounds(info, K, A, free, tie_focal, measured, rig, seeds, rng)}


def free_error_bounds(info: np.ndarray, K: int, A: np.ndarray, free: list[str], tie_focal: bool,
                      measured: tuple[str, ...], rig: str, seeds=(0, 1, 2, 3, 4), rng=None) -> dict:
    """Each reported error's bound after K drives (:func:`median_error_bounds`) for the free variables
    ``free`` (A: :func:`configuration_map`), None for an error whose variables are not all free (a fixed
    variable's error is the fixed value's, not an estimate's)."""
    cov = bound_covariance(info, K, A)
    errs = median_error_bounds(cov, A, measured, rig, seeds, rng if rng is not None else np.random.default_rng(0))
    return {k: (v if all(x in free or (tie_focal and x == "fy") for x in ERROR_VARIABLES[k]) else None)
            for k, v in errs.items()}


def main(argv=None) -> None:
    sys.path.insert(0, str(ROOT / "studies" / "objective"))
    from information_equality import VARS, free_map, typical
    from objective_bias import DRIVE

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--load", type=Path, required=True, help="studies/objective/information_equality.py --save file")
    parser.add_argument("--K", type=int, nargs="+", default=[1, 4, 16], help="calibration drives")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras whose errors are drawn")
    parser.add_argument("--information", choices=["hessian", "opg"], default="hessian",
                        help="the mean Hessian at the truth (default), or the scores' outer product (BHHH)")
    parser.add_argument("--typical", action="store_true",
                        help="only the typical drives (information_equality.typical: curvatures within 5 MADs)")
    parser.add_argument("--frozen", nargs="+", metavar="VAR",
                        help="instead: the errors at the likelihood's limit with these variables held at the reference "
                             "(fy tied to fx on the flat city), e.g. dy dz (the 7-free rows) or cx cy dy dz (the 5-free)")
    parser.add_argument("--sets", type=int, metavar="N",
                        help="instead: the bound of N random K-drive sets of the file's drives, each from its own summed "
                             "Hessian (set_bounds)")
    args = parser.parse_args(argv)
    saved = np.load(args.load)
    if args.frozen:
        return print_frozen(saved, tuple(args.frozen), args.seeds)
    if args.sets:
        return print_sets(saved, args.K, args.sets, args.seeds, np.random.default_rng(0))
    H, g = saved["innovation_nll_joint_H"], saved["innovation_nll_joint_g"]
    keep = typical(H) if args.typical else np.ones(len(H), bool)
    info = fisher_information(H[keep]) if args.information == "hessian" else outer_product_information(g[keep])
    rng = np.random.default_rng(0)
    # the file's rig (files saved before --rig: the flat city, 8 measured, 7 free)
    rig, measured = saved_rig(saved)
    A = free_map(rig, measured)
    names = ("f",) + VARS[2:] if rig == DRIVE else measured
    free = "7 free (fy = fx, dy, dz at the truth)" if rig == DRIVE else f"all {len(measured)} free"
    print(f"Fisher information of the joint likelihood per drive ({keep.sum()}{' typical' if args.typical else ''} "
          f"drives, {'mean Hessian' if args.information == 'hessian' else 'outer product of the scores'}); "
          f"{rig}, {free}")
    print_bounds(info, A, names, measured, rig, args.K, args.seeds, rng)


def print_bounds(info: np.ndarray, A: np.ndarray, names, measured: tuple[str, ...], rig: str, Ks, seeds, rng) -> None:
    """The bound's Markdown table: per number of drives K, each free variable's standard deviation
    (``names``, A's columns) and each reported error's median bound over cameras ``seeds``."""
    print("| K | " + " | ".join(f"σ({n})" for n in names) + " | " + " | ".join(ERRORS) + " |")
    print("|---|" + "---|" * (len(names) + len(ERRORS)))
    for K in Ks:
        cov = bound_covariance(info, K, A)
        errs = median_error_bounds(cov, A, measured, rig, seeds, rng)
        print(f"| {K} | " + " | ".join(f"{s:.3g}" for s in np.sqrt(np.diag(cov))) + " | "
              + " | ".join(f"{errs[k]:.3g}" for k in ERRORS) + " |")


def set_bounds(hessians: np.ndarray, A: np.ndarray, K: int, n_sets: int, rng,
               trajectory: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """The bound drive set by drive set: for ``n_sets`` sets of K of the drives (without replacement),
    ``(A^T (sum of the set's Hessians) A)^-1``, the set's own observed information inverted. Returns
    the covariances (m, r, r) of the m sets whose information is positive definite, and m. The mean
    Hessian's bound ``(K A^T E[H] A)^-1`` is below the mean of these (Jensen), and a set whose summed
    curvature is indefinite at the truth has no quadratic minimum there at all. With ``trajectory``
    (the trajectory of each entry: several noise realisations of one drive) a drive's Hessian is the
    mean over its realisations, its Fisher information given the trajectory with less of the
    observed information's noise."""
    H = 0.5 * (hessians + hessians.transpose(0, 2, 1))
    if trajectory is not None:
        H = np.array([H[trajectory == t].mean(axis=0) for t in np.unique(trajectory)])
    HA = np.einsum("ia,dij,jb->dab", A, H, A)
    covs = []
    for _ in range(n_sets):
        info = HA[rng.choice(len(HA), K, replace=False)].sum(axis=0)
        if np.linalg.eigvalsh(info)[0] > 0:
            covs.append(np.linalg.inv(info))
    return np.array(covs).reshape(-1, A.shape[1], A.shape[1]), len(covs)


def print_sets(saved, Ks, n_sets: int, seeds, rng) -> None:
    """Per K: the share of K-drive sets with a positive definite summed curvature and the median over
    up to 60 of them of each set's error bounds (cameras ``seeds``), beside the mean Hessian's bound."""
    from information_equality import free_map

    rig, measured = saved_rig(saved)
    A = free_map(rig, measured)
    H = saved["innovation_nll_joint_H"]
    trajectory = saved["trajectory"] if "trajectory" in saved else None
    per_drive = "" if trajectory is None else (f" ({len(np.unique(trajectory))} trajectories, each Hessian the mean over "
                                               "its noise realisations)")
    print(f"{rig}, {len(H)} drives{per_drive}: each K-drive set's own observed information (the sum of its drives' "
          f"Hessians at the truth), {n_sets} sets per K")
    print("| K | positive definite sets | " + " | ".join(f"median set bound: {k}" for k in ERRORS) + " | "
          + " | ".join(f"mean-Hessian bound: {k}" for k in ERRORS) + " |")
    print("|---|---|" + "---|" * (2 * len(ERRORS)))
    for K in Ks:
        covs, m = set_bounds(H, A, K, n_sets, rng, trajectory)
        per = {k: [] for k in ERRORS}
        for cov in covs[rng.choice(m, min(60, m), replace=False)] if m else []:
            for k, v in median_error_bounds(cov, A, measured, rig, seeds, rng).items():
                per[k].append(v)
        try:
            mean = median_error_bounds(bound_covariance(fisher_information(H), K, A), A, measured, rig, seeds, rng)
        except np.linalg.LinAlgError:  # the mean Hessian is indefinite (the excited rig's): no such bound
            mean = {}
        print(f"| {K} | {m}/{n_sets} | " + " | ".join(f"{np.median(per[k]):.3g}" if per[k] else "—" for k in ERRORS)
              + " | " + " | ".join(f"{mean[k]:.3g}" if k in mean else "—" for k in ERRORS) + " |")


def print_frozen(saved, fixed: tuple[str, ...], seeds) -> None:
    """The table of :func:`frozen_errors`: per camera and the median."""
    from objective_bias import DRIVE

    rig, _ = saved_rig(saved)
    tie = rig == DRIVE
    try:
        rows = frozen_errors(saved, fixed, tie, seeds)
    except ValueError as err:
        print(f"cramer_rao --frozen {' '.join(fixed)}: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    print(f"The joint likelihood's first-order limit (any number of drives) on {rig} with {', '.join(fixed)} "
          f"held at the reference{' and fy tied to fx' if tie else ''}: the reported errors there")
    print("| camera | " + " | ".join(ERRORS) + " |")
    print("|---|" + "---|" * len(ERRORS))
    for seed, row in zip(seeds, rows):
        print(f"| {seed} | " + " | ".join(f"{row[k]:.3g}" for k in ERRORS) + " |")
    print("| median | " + " | ".join(f"{np.median([r[k] for r in rows]):.3g}" for k in ERRORS) + " |")


if __name__ == "__main__":
    main()
