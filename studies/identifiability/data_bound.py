"""What do a simulated drive's data allow, whatever the estimator? The Cramér–Rao bound of the
simulator's own measurement model, solved as a batch (issue 33).

cramer_rao.py bounds the calibration with the joint innovation likelihood's curvature: a bound only
as far as the filter's model is the data's likelihood, and on the excited rig it is not (its expected
curvature at the truth is indefinite along the lever arm). This bound takes the model that made the
data instead (docs/model.md, Eqs. 58-61): every distinct pixel of the drive's inlier triplet features
(Gaussian, ``pixel_noise_px`` per coordinate, one draw per frame and landmark), the 100 Hz IMU
(white noise and bias random walks of the sequence's ImuNoise) and the filter's prior on the first
state. The unknowns are every frame's IMU state (attitude, position, velocity, biases: 15), every
landmark (3) and the ten calibration variables in the study's local space (px, deg, m); the points
are eliminated through an orthonormal basis of their pixels' Jacobian (:func:`point_directions`),
the states by the Schur complement (Eq. 61). Any unbiased estimator from the same data and prior, the
filter included, has at least this covariance. It knows which features are outliers (they are left out whole), so it is
optimistic there.

Which data (:class:`Pixels`): by default the drive's pixels as they are, a landmark's pixels linked
over every triplet that holds it (the tracks). ``--triplets``: each triplet's features as points of
their own, seen in three images with noise of their own — the measurements as the filter models them
(independent triplets, ``SimConfig.pixel_noise_per_triplet``); ``--max-features 16`` keeps 16 of every
triplet's inliers, as many as an update uses (``FilterConfig.max_update_features``).

    python studies/identifiability/data_bound.py [--rig paper_540m] [--seeds 0 1 2 3 4] [--drives 10] [--K 1 4 16]
        [--triplets] [--max-features 16] [--save F.npz]
    python studies/identifiability/data_bound.py --load F.npz [--K 1 4 16]
    python studies/identifiability/data_bound.py --rig full3d_540m --check 20 [--duration 78]

``--check R`` tests the model against the simulator: over R noise realisations of one trajectory the
linearised maximum-likelihood estimate (one Gauss-Newton step from the truth on each realisation's own
data) must scatter as the bound says (:func:`check`; the flat city's dz, undetermined, leaves no
covariance to compare).

About 4 s of CPU per drive (a 78 s drive: 781 frames, ~50,000 pixels of ~2,100 points); no filter is run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))
sys.path.insert(0, str(ROOT / "studies" / "identifiability"))

from drive_model import CAL_STEP, Pixels, drive_observations, imu_factors, imu_residual, reprojection_jacobians

from avio.sim.simulator import synthesize_imu

#: the local space's variables, the order of the information's rows (cramer_rao.SPACE_VARIABLES)
VARS10 = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz")
STATE = 15  # per frame: attitude (rad, body), position (m), velocity (m/s), accel bias, gyro bias


def point_directions(block: np.ndarray, col_index: np.ndarray, point: np.ndarray, n_cols: int, f: np.ndarray):
    """The information each point's pixels give its own position, as rows ``W`` (sparse, 3 per point,
    ``n_cols`` columns): ``Q^T J`` with Q the orthonormal basis of the point's whitened Jacobian (thin QR)
    and J its pixels' other columns. ``J^T J - W^T W`` is the Schur complement of the points' blocks,
    formed without inverting a 3x3 block that a short baseline leaves nearly singular (Eq. 61).
    block (n, 2, 19): per pixel, columns attitude, position (6), point (3), calibration (10); col_index
    (n, 19); point (n,) its point; f (n, 2) the pixels' whitened residuals. Returns (W, g): g = ``Q^T f``
    per point, so that ``J^T f - W^T g`` is the residual's part the points leave."""
    order = np.argsort(point, kind="stable")
    _, start, count = np.unique(point[order], return_index=True, return_counts=True)
    rows, cols, vals, g = [], [], [], []
    row = 0
    for m in np.unique(count):
        obs = order[start[count == m][:, None] + np.arange(m)]  # (n_m, m) pixels of each point
        b = block[obs]  # (n_m, m, 2, 19)
        n_m = len(obs)
        Q = np.linalg.qr(b[..., 6:9].reshape(n_m, 2 * m, 3))[0].reshape(n_m, m, 2, 3)
        pose = np.einsum("nirq,nirk->nqik", Q, b[..., :6]).reshape(n_m, 3, 6 * m)  # a pixel: its frame's pose
        cal = np.einsum("nirq,nirk->nqk", Q, b[..., 9:])
        W = np.concatenate([pose, cal], axis=2)  # (n_m, 3, 6m + 10)
        c = np.concatenate([col_index[obs][..., :6].reshape(n_m, 6 * m), col_index[obs[:, 0]][:, 9:]], axis=1)
        g.append(np.einsum("nirq,nir->nq", Q, f[obs]).ravel())
        rows.append(np.repeat(row + np.arange(3 * n_m), W.shape[2]))
        cols.append(np.repeat(c, 3, axis=0).ravel())
        vals.append(W.ravel())
        row += 3 * n_m
    W = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row, n_cols))
    return W, np.concatenate(g)


def drive_information(seq, world, decode, x_truth: np.ndarray, pixels: Pixels = Pixels(), rng=None) -> np.ndarray:
    """(10, 10) Fisher information of the calibration's local variables (VARS10) on one simulated drive,
    every frame state and landmark marginalised out (module docstring; decode: the problem's local
    space decode, x_truth its truth there)."""
    return calibration_information(*drive_jacobian(seq, world, decode, x_truth, pixels, rng)[:3])


def calibration_information(J, n_x: int, W=None) -> np.ndarray:
    """(10, 10) Schur complement of ``J^T J - W^T W`` onto its last 10 columns (Eq. 61; J: the whitened
    Jacobian, sparse, its first n_x columns the unknowns marginalised out; W: :func:`point_directions`)."""
    info = (J.T @ J - (W.T @ W if W is not None else 0)).tocsc()
    d = info.diagonal()
    scale = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))  # equilibrated: the states' information spans ~12 decades
    info = (sp.diags(scale) @ info @ sp.diags(scale)).tocsc()
    I_xx, I_xc, I_cc = info[:n_x, :n_x], info[:n_x, n_x:].toarray(), info[n_x:, n_x:].toarray()
    # a minimum-degree ordering of the symmetric pattern: SuperLU's default took 20x longer on a 78 s drive
    lu = splu(I_xx, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    I_cal = (I_cc - I_xc.T @ lu.solve(I_xc)) / np.outer(scale[n_x:], scale[n_x:])
    return 0.5 * (I_cal + I_cal.T)


def drive_jacobian(seq, world, decode, x_truth: np.ndarray, pixels: Pixels = Pixels(), rng=None, points: bool = False):
    """(J, n_x, W, f, g): the whitened Jacobian (sparse CSR, rows: residuals of Eqs. 58, 60, the bias walks and
    the prior; columns: 15 per frame, then the 10 calibration variables) at the truth, the number of
    columns before the calibration's, the points' rows to subtract (:func:`point_directions`; with
    ``points`` the points are columns instead, 3 per point after the frames', and W, g are None), the
    whitened residuals at the truth, model minus measurement, row by row: the drive's own noise (the
    IMU's without the Euler step's error: its noise-free samples' residual subtracted), and W's (g)."""
    from avio.filter.config import FilterConfig

    frame_t = seq.frame_t_s
    N = len(frame_t)
    st = world.trajectory(frame_t)
    at = np.searchsorted(seq.imu.t_s, frame_t - 1e-9)
    per = int(at[1] - at[0])
    if not np.all(np.diff(at) == per) or not np.allclose(seq.imu.t_s[at], frame_t):
        raise ValueError(f"{seq.name}: frames must fall on IMU samples at a fixed ratio")
    ba, bg = world.accel_bias_mps2[at], world.gyro_bias_radps[at]
    frame, lm, lm_col, uv = drive_observations(seq, world, pixels, rng)
    L = int(lm_col.max()) + 1 if points else 0
    n_x = STATE * N + 3 * L
    rows, cols, vals, res = [], [], [], []
    row = 0

    def put(block: np.ndarray, col_index: np.ndarray, f: np.ndarray) -> None:
        """Rows (n, r, c) of the whitened Jacobian with columns (n, c), and their residuals (n, r)."""
        nonlocal row
        n, r, c = block.shape
        rr = row + np.arange(n * r).reshape(n, r)
        rows.append(np.repeat(rr[:, :, None], c, axis=2).ravel())
        cols.append(np.broadcast_to(col_index[:, None, :], (n, r, c)).ravel())
        vals.append(block.ravel())
        res.append(np.broadcast_to(f, (n, r)).ravel())
        row += n * r

    # pixels (Eq. 58)
    X = decode(np.repeat(x_truth[None], 21, axis=0) + np.vstack([np.diag(CAL_STEP), -np.diag(CAL_STEP), np.zeros(10)]))
    Jp = reprojection_jacobians(st.R_world_imu[frame], st.p_world_imu_m[frame], world.landmarks_world[lm],
                                X[20:], X[:10], X[10:20])
    sigma = float(seq.meta["config"]["pixel_noise_px"])
    block = np.concatenate([Jp["theta"], Jp["p"], Jp["X"], Jp["cal"]], axis=2) / sigma
    col_index = np.concatenate([STATE * frame[:, None] + np.arange(6), STATE * N + 3 * lm_col[:, None] + np.arange(3),
                                np.broadcast_to(n_x + np.arange(10), (len(frame), 10))], axis=1)
    f_pix = (Jp["uv"] - uv) / sigma
    W, g = None, None
    if points:
        put(block, col_index, f_pix)
    else:  # the points' columns dropped, their information subtracted (W)
        put(block[..., np.r_[0:6, 9:19]], col_index[:, np.r_[0:6, 9:19]], f_pix)
        W, g = point_directions(block, col_index, lm_col, n_x + 10, f_pix)
    # IMU between consecutive frames (Eqs. 59-61)
    dt = float(np.median(np.diff(seq.imu.t_s)))
    idx = at[:-1, None] + np.arange(per)
    noise = seq.imu_noise
    truth = (st.R_world_imu[:-1], st.p_world_imu_m[:-1], st.v_world_imu_mps[:-1], ba[:-1], bg[:-1],
             st.R_world_imu[1:], st.p_world_imu_m[1:], st.v_world_imu_mps[1:])
    gyro, accel, grav = seq.imu.gyro_imu_radps[idx], seq.imu.accel_imu_mps2[idx], seq.gravity_world_mps2
    Ji, Li = imu_factors(truth, gyro, accel, dt, grav, noise.accel_noise / np.sqrt(dt), noise.gyro_noise / np.sqrt(dt))
    clean = synthesize_imu(world.trajectory, seq.imu.t_s[idx].ravel(), grav, None, np.zeros(3), np.zeros(3), None)[0]
    accel0 = clean.accel_imu_mps2.reshape(accel.shape) + world.accel_bias_mps2[idx]  # the samples without noise
    gyro0 = clean.gyro_imu_radps.reshape(gyro.shape) + world.gyro_bias_radps[idx]
    z0, z1 = np.zeros((N - 1, 15)), np.zeros((N - 1, 9))
    f_imu = np.linalg.solve(Li, (imu_residual(truth, z0, z1, gyro, accel, dt, grav)
                                 - imu_residual(truth, z0, z1, gyro0, accel0, dt, grav))[..., None])[..., 0]
    k = np.arange(N - 1)[:, None]
    put(Ji, np.concatenate([STATE * k + np.arange(15), STATE * (k + 1) + np.arange(9)], axis=1), f_imu)
    # bias random walks
    T = dt * per
    walk = np.r_[[noise.accel_bias_walk * np.sqrt(T)] * 3, [noise.gyro_bias_walk * np.sqrt(T)] * 3]
    eye = np.eye(6) / walk
    put(np.concatenate([np.broadcast_to(-eye, (N - 1, 6, 6)), np.broadcast_to(eye, (N - 1, 6, 6))], axis=2),
        np.concatenate([STATE * k + 9 + np.arange(6), STATE * (k + 1) + 9 + np.arange(6)], axis=1),
        np.diff(np.concatenate([ba, bg], axis=1), axis=0) / walk)
    # the filter's prior on the first state (Eq. 9)
    fc = FilterConfig()
    prior = np.r_[[fc.init_sigma_theta_rad] * 3, [fc.init_sigma_p_m] * 3, [fc.init_sigma_v_mps] * 3,
                  [fc.init_sigma_ba_mps2] * 3, [fc.init_sigma_bg_radps] * 3]
    put(np.diag(1 / prior)[None], np.arange(15)[None], np.zeros(15))  # the filter starts at the truth
    J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row, n_x + 10))
    return J, n_x, W, np.concatenate(res), g


def linearised_estimate(seq, world, decode, x_truth: np.ndarray, rng, pixels: Pixels = Pixels()):
    """One Gauss-Newton step from the truth on the drive's own noisy data (:func:`drive_jacobian`'s
    residuals; the prior's, zero for the filter, drawn with ``rng`` as its sigmas say): the linearised
    maximum-likelihood estimate's calibration error (10,) in the local variables, and the drive's
    information (10, 10). Over noise realisations the errors' covariance is the bound where the model's
    noise is the simulator's (:func:`check`)."""
    J, n_x, W, f, g = drive_jacobian(seq, world, decode, x_truth, pixels)
    f[-15:] = rng.standard_normal(15)  # the prior's rows come last
    normal = (J.T @ J - W.T @ W).tocsc()
    scale = 1.0 / np.sqrt(normal.diagonal())
    step = -scale * splu((sp.diags(scale) @ normal @ sp.diags(scale)).tocsc(), permc_spec="MMD_AT_PLUS_A").solve(
        scale * (J.T @ f - W.T @ g))
    return step[n_x:], calibration_information(J, n_x, W)


def check(rig: str, seed: int, realisations: int, duration_s: float, pixels: Pixels = Pixels()) -> dict:
    """The bound against the scatter of :func:`linearised_estimate` over ``realisations`` noise realisations of
    one trajectory of camera ``seed`` (``duration_s`` long): ``ratio`` (10,) each variable's variance over its
    bound, ``trace`` ``tr(I C) / 10`` (1 where the model's noise is the drive's), ``t`` (10,) each mean error's
    t-statistic (0: no bias)."""
    from information_equality import reference_all_problem
    from objective_bias import FRESH_SEED0

    from avio.sim.simulator import SimConfig, simulate_world
    from bench.problems.synthetic import NOISE_WORD

    problem = reference_all_problem(seed, rig)
    rng = np.random.default_rng(seed)
    errors, infos = [], []
    for r in range(1, realisations + 1):
        seq, world = simulate_world(getattr(SimConfig, rig)(duration_s=duration_s), (seed, FRESH_SEED0),
                                    true_calibration=problem.sequence.truth_calibration,
                                    noise_seed=(seed, FRESH_SEED0, NOISE_WORD, r))
        e, info = linearised_estimate(seq, world, problem.calibration_space.decode, problem.truth, rng, pixels)
        errors.append(e)
        infos.append(info)
    errors, info = np.array(errors), np.mean(infos, axis=0)
    C = np.cov(errors.T)
    return {"ratio": np.diag(C) / np.diag(np.linalg.inv(info)),
            "trace": float(np.trace(info @ C) / len(info)),
            "t": errors.mean(axis=0) / (errors.std(axis=0, ddof=1) / np.sqrt(len(errors)))}


def measure(rig: str, seeds, n_drives: int, pixels: Pixels = Pixels()) -> dict:
    """Per fresh drive of each camera (studies/objective/information_equality.py's drives: ``(seed, 100 + i)``
    of the rig's preset, the camera's truth) the (10, 10) information (:func:`drive_information`)."""
    from information_equality import reference_all_problem
    from objective_bias import FRESH_SEED0

    from avio.sim.simulator import SimConfig, simulate_world

    out, trajectory = [], []
    rng = np.random.default_rng(0)
    for seed in seeds:
        problem = reference_all_problem(seed, rig)
        cols = [problem.space.names.index(v) for v in VARS10]
        if cols != list(range(10)):
            raise ValueError(f"the local space's first ten variables are not {VARS10}")
        for i in range(n_drives):
            seq, world = simulate_world(getattr(SimConfig, rig)(), (seed, FRESH_SEED0 + i),
                                        true_calibration=problem.sequence.truth_calibration)
            decode = problem.calibration_space.decode
            out.append(drive_information(seq, world, decode, problem.truth, pixels, rng))
            trajectory.append(1000 * seed + i)
    return {"information": np.array(out), "trajectory": np.array(trajectory, dtype=np.int64)}


def undetermined(info: np.ndarray, free: list[str], A: np.ndarray, tol: float = 1e-9) -> list[str]:
    """The free variables on which the data carry no information: their own information in ``A^T info A``
    (numerically zero, either sign) at most ``tol`` times the largest (the flat city's dz: ~1e-6 per m^2
    against ~1e4 for dx)."""
    d = np.diag(A.T @ info @ A)
    return [v for v, x in zip(free, d) if x <= tol * d.max()]


def configuration_bound(saved, K: int, fixed=(), tie_focal: bool = False, with_time_offset: bool = False,
                        seeds=(0, 1, 2, 3, 4), rng=None) -> dict | None:
    """The data's bound on each reported error of a study configuration (as cramer_rao.configuration_bound,
    from a ``--save`` file of this script, loaded): None with the time offset free (not modelled here);
    an error whose variables are not all free gets None, and so does one whose variables the data do not
    determine (:func:`undetermined`; the other errors' bounds are then taken with those at the truth: with
    no information they carry no cross-information either)."""
    from cramer_rao import configuration_map, free_error_bounds

    mapped = configuration_map(VARS10, fixed, tie_focal, with_time_offset)
    if mapped is None:
        return None
    info = saved["information"].mean(axis=0)
    A, free = mapped
    lost = undetermined(info, free, A)
    if lost:
        A, free = configuration_map(VARS10, tuple(fixed) + tuple(lost), tie_focal)
    return free_error_bounds(info, K, A, free, tie_focal, VARS10, str(saved["rig"]), seeds, rng)


def main(argv=None) -> None:
    from cramer_rao import configuration_map, print_bounds

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", default="paper_540m", choices=["paper_540m", "full3d_540m"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="cameras")
    parser.add_argument("--drives", type=int, default=10, help="fresh drives per camera")
    parser.add_argument("--K", type=int, nargs="+", default=[1, 4, 16], help="calibration drives")
    parser.add_argument("--max-features", type=int, help="keep this many inlier features of every triplet")
    parser.add_argument("--triplets", action="store_true",
                        help="each triplet feature its own point and pixels (Pixels)")
    parser.add_argument("--check", type=int, metavar="R",
                        help="instead: the bound against the linearised ML estimate's scatter over R noise "
                             "realisations of one trajectory of the first camera (check)")
    parser.add_argument("--duration", type=float, default=78.0, help="--check: the drive's length, s")
    parser.add_argument("--save", type=Path)
    parser.add_argument("--load", type=Path)
    args = parser.parse_args(argv)
    if args.check:
        out = check(args.rig, args.seeds[0], args.check, args.duration, Pixels(args.max_features, args.triplets))
        print(f"{args.rig}, camera {args.seeds[0]}, {args.duration:g} s, {args.check} noise realisations: "
              f"tr(I C)/10 = {out['trace']:.2f}")
        print("| | " + " | ".join(VARS10) + " |\n|---|" + "---|" * 10)
        print("| variance ÷ bound | " + " | ".join(f"{v:.2f}" for v in out["ratio"]) + " |")
        print("| mean error's t | " + " | ".join(f"{v:+.2f}" for v in out["t"]) + " |")
        return
    if args.load:
        saved = np.load(args.load)
        rig, info = str(saved["rig"]), saved["information"]
        pixels = Pixels(int(saved["max_features"]) or None, bool(saved["triplets"]))
    else:
        t0 = time.process_time()
        pixels = Pixels(args.max_features, args.triplets)
        data = measure(args.rig, args.seeds, args.drives, pixels)
        rig, info = args.rig, data["information"]
        print(f"{len(info)} drives of {rig} in {time.process_time() - t0:.0f} s CPU")
        if args.save:
            np.savez(args.save, rig=rig, vars=np.array(VARS10), max_features=args.max_features or 0,
                     triplets=args.triplets, **data)
    mean = info.mean(axis=0)
    rng = np.random.default_rng(0)
    configurations = {"all 10 free": ((), False), "9 free (dz at the truth)": (("dz",), False),
                      "7 free (fy = fx, dy, dz at the truth)": (("dy", "dz"), True)}
    for label, (fixed, tie) in configurations.items():
        A, free = configuration_map(VARS10, fixed, tie)
        which = ("independent triplets" if pixels.triplets else "the tracks") + (
            f", {pixels.max_features} features a triplet" if pixels.max_features else "")
        print(f"\nCramér–Rao bound of the data ({which}), {rig}, {label}: {len(info)} drives' mean information")
        lost = undetermined(mean, free, A)
        if lost:
            print(f"not identifiable: the data determine nothing along {', '.join(lost)}")
            continue
        print_bounds(mean, A, free, VARS10, rig, args.K, args.seeds, rng)


if __name__ == "__main__":
    main()
