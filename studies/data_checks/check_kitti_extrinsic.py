"""Do the rectified KITTI camera's rays match what the real tracks see? A check from the real
tracks alone, independent of the filter.

What it measures is the camera's *rays* (the extrinsic rotation and the intrinsics together),
not the extrinsic alone: the essential matrix is computed with the rectified intrinsics, so a
principal point ~5 px off moves the epipole as a ~0.4 deg rotation does (issue 33).

The ground-truth poses of KITTI 00 (``KITTI_00_gt.txt``) are the OXTS poses carried into the
rectified cam0 frame through KITTI's calibration chain (``R_rect_00 T_cam_velo T_velo_imu``,
avio/reference.py): if the chain's rotation is off by D (``R_true = D R_rect``), the truth's
camera-frame translation between two frames, ``c_gt = R_k^T (p_k+1 - p_k)``, is off by D from
the translation the images see. The images see it in the epipole: the essential matrix of the
real tracks between frames k and k+1 (OpenCV, RANSAC, the rectified intrinsics) gives the
direction ``c_vis`` of camera k+1's centre in camera k. For a car moving forward (c ~ +z),
``c_vis - c_gt ~ (D_y, -D_x, 0)``: the median angles between them about the camera's y axis
(``atan2(x, z)``) and x axis (``atan2(y, z)``) over the window's frame pairs estimate D's x and y
components (D_z, about the optical axis, moves no translation direction). Errors are bootstrap
standard errors of the medians (the OXTS positions move ~1 cm between frames 1 m apart: ~0.5 deg
of noise per pair).

Beside it, the camera-frame correction ``D = R_opt R_rect^T`` of the committed rotation-only
likelihood runs (results/kitti00_tracks_nll_rotation), so the two can be compared.

    python studies/data_checks/check_kitti_extrinsic.py [--data DIR] [--first 15] [--last 153]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from avio.datasets.kitti00 import TRACKS_FILE, read_kitti00, read_real_tracks
from avio.reference import CX_PX, CY_PX, FX_PX, FY_PX, kitti_2011_10_03_calibration

MIN_STEP_M = 0.3  # frame pairs closer than this carry too little translation to read a direction from
MIN_COMMON = 30  # landmarks seen in both frames, for the essential matrix


def direction_offsets(data_dir: Path, first: int, last: int, chain_rotation: np.ndarray | None = None,
                      method: str = "essential") -> np.ndarray:
    """(n, 2) per frame pair k, k+1 of the window: visual minus ground-truth translation direction,
    degrees, about the camera's y axis and about its x axis. chain_rotation (3, 3): a camera-frame
    rotation Delta applied to the chain (``R_rect -> Delta R_rect``, so the truth's camera
    orientations become ``R_W_cam Delta^T``); the estimate of D then moves by about -Delta.
    method: ``essential`` (the epipole of the 2-D tracks alone) or ``pnp`` (the tracks' stereo
    points of frame k, triangulated by KITTI, against their pixels in frame k+1: metric, so the
    rotation-translation ambiguity of forward motion cannot bias it)."""
    raw = read_kitti00(data_dir / "kitti00")
    frame, landmark, uv, xyz = read_real_tracks(data_dir / "kitti00" / TRACKS_FILE, first, last, with_points=True)
    K = np.array([[FX_PX, 0.0, CX_PX], [0.0, FY_PX, CY_PX], [0.0, 0.0, 1.0]])
    out = []
    for k in range(first, last):
        a, b = frame == k, frame == k + 1
        _, ia, ib = np.intersect1d(landmark[a], landmark[b], return_indices=True)
        Tk, Tk1 = raw.T_W_cam0[k], raw.T_W_cam0[k + 1]
        c_gt = Tk[:3, :3].T @ (Tk1[:3, 3] - Tk[:3, 3])
        if chain_rotation is not None:
            c_gt = chain_rotation @ c_gt
        if len(ia) < MIN_COMMON or np.linalg.norm(c_gt) < MIN_STEP_M:
            continue
        p1, p2 = uv[a][ia], uv[b][ib]
        if method == "essential":
            E, inliers = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=0.9999, threshold=0.5)
            _, R, t, _ = cv2.recoverPose(E, p1, p2, K, mask=inliers)
        else:
            ok, rvec, t, _ = cv2.solvePnPRansac(xyz[a][ia], p2, K, None, reprojectionError=1.0,
                                                iterationsCount=500, flags=cv2.SOLVEPNP_ITERATIVE)
            if not ok:
                continue
            R = cv2.Rodrigues(rvec)[0]
        c_vis = (-R.T @ t).ravel()  # camera k+1's centre in camera k (OpenCV: x2 = R x1 + t)
        out.append([np.degrees(np.arctan2(c_vis[0], c_vis[2]) - np.arctan2(c_gt[0], c_gt[2])),
                    np.degrees(np.arctan2(c_vis[1], c_vis[2]) - np.arctan2(c_gt[1], c_gt[2]))])
    return np.array(out)


def chain_correction_deg(offsets: np.ndarray) -> tuple[float, float]:
    """(D_x, D_y) deg, the chain's camera-frame correction, from :func:`direction_offsets`."""
    return -float(np.median(offsets[:, 1])), float(np.median(offsets[:, 0]))


def bootstrap_median_se(x: np.ndarray, n: int = 2000, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    return float(np.std([np.median(rng.choice(x, len(x))) for _ in range(n)]))


def committed_likelihood_corrections(folder: Path) -> list[np.ndarray]:
    """Camera-frame rotation vectors (deg) ``log(R_opt R_rect^T)`` of the committed runs in folder."""
    from bench.problems.base import build_problem

    rect = kitti_2011_10_03_calibration(rectified=True).R_cam_imu[0]
    out = []
    from bench.archive import job_records

    for _, record in job_records(folder):  # files or records.tar.xz
        if record.get("status") != "ok":
            continue
        problem = build_problem(record["config"])
        cal = problem.calibration_space.decode(np.asarray(record["best_x"], float)[None])
        out.append(np.degrees(Rotation.from_matrix(cal.R_cam_imu[0] @ rect.T).as_rotvec()))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="data folder (default: AVIO_DATA or ../shared/data)")
    parser.add_argument("--first", type=int, default=15)
    parser.add_argument("--last", type=int, default=153)
    args = parser.parse_args(argv)
    if args.data is None:
        from bench.problems.vio import default_data_dir

        args.data = default_data_dir()
    for method in ("essential", "pnp"):
        d = direction_offsets(args.data, args.first, args.last, method=method)
        yaw, pitch = d[:, 0], d[:, 1]
        dx, dy = chain_correction_deg(d)
        print(f"frames {args.first}-{args.last}, {method}: {len(d)} frame pairs; visual minus ground-truth translation "
              f"direction (median, bootstrap SE; quartiles):")
        print(f"  about the camera's y axis {np.median(yaw):+.3f} +- {bootstrap_median_se(yaw):.3f} deg "
              f"({np.percentile(yaw, 25):+.2f}, {np.percentile(yaw, 75):+.2f})")
        print(f"  about the camera's x axis {np.median(pitch):+.3f} +- {bootstrap_median_se(pitch):.3f} deg "
              f"({np.percentile(pitch, 25):+.2f}, {np.percentile(pitch, 75):+.2f})")
        print(f"  -> the chain's camera-frame correction D ~ ({dx:+.3f}, {dy:+.3f}, ?) deg about (x, y, z): "
              f"{np.hypot(dx, dy):.2f} deg without its unseen z part")
    folder = ROOT / "results" / "kitti00_tracks_nll_rotation"
    runs = committed_likelihood_corrections(folder) if folder.exists() else []
    for v in runs:
        print(f"  likelihood, rotation only (results/{folder.name}): D = ({v[0]:+.3f}, {v[1]:+.3f}, {v[2]:+.3f}) deg, "
              f"{np.linalg.norm(v):.2f} deg from the rectified extrinsic; {np.hypot(v[0] - dx, v[1] - dy):.2f} deg "
              f"from the pnp estimate in x, y")


if __name__ == "__main__":
    main()
