"""Print the simulator's figures: timings, drive lengths, IMU consistency, tracks, render accuracy.

Usage: python studies/data_checks/check_simulator.py [--seed 0] [--render-frames 30]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "avio" / "sim"))

from test_simulator import _integrate_rk4

from avio.geometry import geodesic_angle_deg
from avio.sim.render import load_projections, render_frames
from avio.sim.simulator import SimConfig, simulate, simulate_world


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--render-frames", type=int, default=30)
    args = parser.parse_args()

    simulate(SimConfig.paper_540m(duration_s=5.0), args.seed)  # warm imports
    for name, preset in (("paper_540m", SimConfig.paper_540m), ("paper_928m", SimConfig.paper_928m)):
        t0 = time.perf_counter()
        seq = simulate(preset(), args.seed)
        elapsed = time.perf_counter() - t0
        n = seq.tracks.n_features
        ref, true = seq.reference_calibration, seq.truth_calibration
        print(
            f"{name}: simulate {elapsed:.2f} s | {seq.path_length_m():.1f} m in "
            f"{seq.frame_t_s[-1] - seq.frame_t_s[0]:.1f} s | {seq.n_frames} frames, {len(seq.imu.t_s)} IMU | "
            f"features/triplet median {np.median(n):.0f}, min {n.min()} | landmarks {seq.meta['n_landmarks']} | "
            f"truth-ref: fx {true.fx_px[0] - ref.fx_px[0]:+.2f} px, cy {true.cy_px[0] - ref.cy_px[0]:+.2f} px, "
            f"rot {geodesic_angle_deg(ref.R_cam_imu[0], true.R_cam_imu[0]):.2f} deg, "
            f"trans {100 * np.linalg.norm(true.p_imu_cam_m - ref.p_imu_cam_m):.1f} cm"
        )
        quiet, _ = simulate_world(preset(imu_noise_on=False), args.seed)
        p, R_end = _integrate_rk4(quiet.imu.t_s, quiet.imu.accel_imu_mps2, quiet.imu.gyro_imu_radps,
                                  quiet.gravity_world_mps2, quiet.truth.p_world_imu_m[0],
                                  quiet.truth.v_world_imu_mps[0], quiet.truth.R_world_imu[0])
        err = np.linalg.norm(p[::5] - quiet.truth.p_world_imu_m, axis=1)
        print(f"  noiseless IMU + RK4 from the truth start: max position error {err.max():.2e} m, "
              f"final attitude error {geodesic_angle_deg(R_end, quiet.truth.R_world_imu[-1]):.2e} deg")

    seq, world = simulate_world(SimConfig.paper_540m(), args.seed)
    speed = np.linalg.norm(seq.truth.v_world_imu_mps, axis=1)
    start = int(np.argmax(speed[: -args.render_frames]))  # a stretch at cruising speed, not the stop
    frames = seq.frame_t_s[start : start + args.render_frames]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        paths = render_frames(world.trajectory, frames, seq.truth_calibration, world.landmarks_world,
                              seq.image_size_px, tmp, np.random.default_rng(args.seed))
        elapsed = time.perf_counter() - t0
        obs, _ = load_projections(tmp)
        errors = []
        for k in range(len(paths) - 1):  # KLT from each true position to the next frame
            a, b = cv2.imread(paths[k], cv2.IMREAD_GRAYSCALE), cv2.imread(paths[k + 1], cv2.IMREAD_GRAYSCALE)
            i0, i1 = obs.frame_index == k, obs.frame_index == k + 1
            common, j0, j1 = np.intersect1d(obs.landmark_id[i0], obs.landmark_id[i1], return_indices=True)
            uv0, uv1 = obs.uv_px[i0][j0], obs.uv_px[i1][j1]
            tracked, status, _ = cv2.calcOpticalFlowPyrLK(a, b, uv0.astype(np.float32), None, winSize=(21, 21),
                                                          maxLevel=3)
            errors.append(np.linalg.norm(tracked - uv1, axis=1)[status[:, 0] == 1])
        errors = np.concatenate(errors)
        print(f"render: {elapsed / len(paths) * 1000:.0f} ms/frame | KLT from the true pixel to the next frame: "
              f"median {np.median(errors):.3f} px, 75% {np.quantile(errors, 0.75):.2f} px, "
              f"90% {np.quantile(errors, 0.9):.2f} px over {len(errors)} tracks")


if __name__ == "__main__":
    main()
