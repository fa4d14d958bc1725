"""Print the figures that check the KITTI loaders and the KLT front end on the real data.

Usage: python studies/data_checks/check_kitti.py [DATA_DIR]   (default ../shared/data from the repo root)
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.integrate import cumulative_trapezoid

from avio.datasets.kitti00 import DEFAULT_DATA_DIR, WINDOWS, kitti00_truth, load_kitti00
from avio.datasets.kitti_raw import load_kitti_raw
from avio.frontend.klt import track_images, track_observations
from avio.geometry import so3_exp, so3_log


def kitti00_figures(data: Path) -> None:
    g = kitti00_truth(data / "kitti00").g_W_mps2
    print(f"kitti00 gravity in GT world: {np.round(g, 4)} |g| = {np.linalg.norm(g):.4f} m/s^2")
    for name, (a, b) in WINDOWS.items():
        seq = load_kitti00(data / "kitti00", a, b, max_gt_rate_misfit_radps=None)  # paper_928m holds defects
        t, gt, imu = seq.frame_t_s, seq.truth, seq.imu
        cum = cumulative_trapezoid(imu.gyro_imu_radps, imu.t_s, axis=0, initial=0.0)
        def at(x):
            return np.stack([np.interp(x, imu.t_s, cum[:, j]) for j in range(3)], 1)
        w_imu = (at(t[1:]) - at(t[:-1])) / np.diff(t)[:, None]
        R0 = gt.R_world_imu[:-1]
        w_gt = so3_log(np.swapaxes(R0, 1, 2) @ gt.R_world_imu[1:]) / np.diff(t)[:, None]
        wi, wg = np.einsum("nij,nj->ni", R0, w_imu), np.einsum("nij,nj->ni", R0, w_gt)
        corr = [np.corrcoef(wi[:, j], wg[:, j])[0, 1] for j in range(3)]
        err = one_second_errors(seq)
        print(f"{name} frames {a}-{b}: {seq.path_length_m():.1f} m, {t[-1] - t[0]:.2f} s; gyro vs GT rate "
              f"correlation all {np.corrcoef(wi.ravel(), wg.ravel())[0, 1]:.4f} (world x/y/z "
              f"{corr[0]:.3f}/{corr[1]:.3f}/{corr[2]:.4f}); 1-s IMU integration from GT: median "
              f"{np.median(err):.3f} m, 90% {np.percentile(err, 90):.3f} m, max {err.max():.3f} m")
    seq = load_kitti00(data / "kitti00", 15, 153, camera="real_tracks", max_features=None)
    n = seq.tracks.n_features
    print(f"real tracks 15-153: features per triplet median {np.median(n):.0f}, empty triplets "
          f"{seq.meta['triplets_without_tracks'][0]}..{seq.meta['triplets_without_tracks'][-1]}")


def one_second_errors(seq) -> np.ndarray:
    """Position error (m) after integrating the IMU for 10 frames from each 10th GT state."""
    gt, t, imu, g = seq.truth, seq.frame_t_s, seq.imu, seq.gravity_world_mps2
    errors = []
    for i0 in range(0, len(t) - 11, 10):  # independent 1-s runs: a diagnostic, not the filter
        R, p, v = gt.R_world_imu[i0], gt.p_world_imu_m[i0], gt.v_world_imu_mps[i0]
        ts = np.r_[t[i0], imu.t_s[(imu.t_s > t[i0]) & (imu.t_s < t[i0 + 10])], t[i0 + 10]]
        idx = np.searchsorted(imu.t_s, ts[:-1], side="right") - 1
        for dt, j in zip(np.diff(ts), idx):
            a = R @ imu.accel_imu_mps2[j] + g
            p, v, R = p + v * dt + 0.5 * a * dt**2, v + a * dt, R @ so3_exp(imu.gyro_imu_radps[j] * dt)
        errors.append(np.linalg.norm(p - gt.p_world_imu_m[i0 + 10]))
    return np.array(errors)


def raw_figures(data: Path) -> None:
    seq = load_kitti_raw(data / "kitti_raw_2011_09_26_drive_0001" / "2011_09_26_drive_0001_sync")
    p, v, t = seq.truth.p_world_imu_m, seq.truth.v_world_imu_mps, seq.frame_t_s
    length = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum()
    integ = np.trapezoid(np.hypot(v[:, 0], v[:, 1]), t)
    pv = cumulative_trapezoid(v, t, axis=0, initial=0.0)
    def chord(q):
        return np.unwrap(np.arctan2(q[10:, 1] - q[:-10, 1], q[10:, 0] - q[:-10, 0]))
    print(f"raw 2011_09_26_drive_0001: path {length:.2f} m vs integrated OXTS speed {integ:.2f} m "
          f"({100 * (length / integ - 1):+.2f}%), end point off by {np.linalg.norm(pv[-1] - p[-1]):.2f} m; "
          f"heading change {np.degrees(chord(p)[-1] - chord(p)[0]):.2f} deg (positions) vs "
          f"{np.degrees(chord(pv)[-1] - chord(pv)[0]):.2f} deg (velocities)")


def frontend_figures(data: Path) -> None:
    paths = sorted((data / "kitti_gray_2011_09_26").glob("*.png"))
    start = time.perf_counter()
    tracks, stats = track_images(paths)
    print(f"KLT on 10 real frames ({time.perf_counter() - start:.2f} s): surviving tracks per pair "
          f"{stats.n_inliers.tolist()}, median FB error {np.round(stats.fb_median_px, 3).tolist()} px, "
          f"features per triplet {tracks.n_features.tolist()}")
    from avio.sim.render import load_projections
    from avio.sim.simulator import SimConfig, simulate

    with tempfile.TemporaryDirectory() as tmp:
        seq = simulate(SimConfig(duration_s=1.5, output="images"), seed=1, image_dir=tmp)
        obs, _, _ = track_observations(seq.image_paths)
        truth, _ = load_projections(Path(seq.image_paths[0]).parent)
    lookup = {(int(f), int(lm)): uv for f, lm, uv in zip(truth.frame_index, truth.landmark_id, truth.uv_px)}
    by_frame = {}
    for f, lm, uv in zip(truth.frame_index, truth.landmark_id, truth.uv_px):
        by_frame.setdefault(int(f), []).append((lm, uv))
    errors, origin = [], {}
    for f, tid, uv in sorted(zip(obs.frame_index, obs.track_id, map(tuple, obs.uv_px)), key=lambda r: (r[1], r[0])):
        if tid not in origin:
            cands = by_frame[int(f)]
            d = [np.hypot(*(np.asarray(uv) - c)) for _, c in cands]
            k = int(np.argmin(d))
            origin[tid] = (int(f), int(cands[k][0]), np.asarray(uv)) if d[k] < 1.5 else None
        elif origin[tid] is not None:
            f0, lm, uv0 = origin[tid]
            if (int(f), lm) in lookup:
                errors.append(np.linalg.norm((np.asarray(uv) - uv0) - (lookup[(int(f), lm)] - lookup[(f0, lm)])))
    print(f"KLT on rendered simulated frames: median tracking error {np.median(errors):.3f} px "
          f"over {len(errors)} observations")


if __name__ == "__main__":
    data = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_DATA_DIR
    kitti00_figures(data)
    raw_figures(data)
    frontend_figures(data)
