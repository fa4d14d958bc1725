"""The EuRoC V1_01 loader's facts, and the filter's accuracy at the Kalibr calibration.

Prints what the loader read (clocks, calibration, noise, biases, tracks), the feature count of
every triplet, and for each window and initial-bias choice the filter's position RMSE,
attitude RMSE and drift per metre of path at the Kalibr calibration, over several feature
draws (``FilterConfig.bucket_seed``: which ~16 of the ~23 features a frame uses moves the
RMSE by 0.01-0.03 m, so one draw means little). Drift: ``drift m/m`` is
avio.metrics.drift_metrics (mean translation error over 1 m path segments, per metre);
``end err/path %`` the final position error over the path length.

    python studies/data_checks/check_euroc.py [--data-dir DIR] [--seeds 0 1 2 3 4] [--min-parallax 0.005]
        [--imu-variance-ratio 1e6]

The filter settings are the EuRoC problem's (bench/conf/problem/euroc.yaml): ``min_parallax_m``
0.005 (frames are 1.4 cm apart) and ``stationary_imu_variance_ratio`` 1e6, i.e. the standstill
is detected from the images alone: on the ground the MAV's running rotors shake the IMU to
12-1500 times its white-noise variance (1 s windows; 160-6000 in flight), so the IMU test never
passes and 5 s of standstill go without a zero-velocity update. The script prints the 0-30 s
figure with the filter's default ratio too, to show it.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from avio.datasets.euroc import DEFAULT_DATA_DIR, EurocDataError, load_euroc, read_euroc
from avio.filter.batch import run
from avio.filter.config import FilterConfig
from avio.geometry import geodesic_angle_deg
from avio.metrics import drift_metrics, pose_errors, position_rmse_objective

WINDOWS_S = ((0.0, 30.0), (0.0, 20.0), (20.0, 30.0))
BIAS_INITS = ("ground_truth", "standstill", "zero")


def loader_facts(data_dir) -> None:
    raw = read_euroc(data_dir)
    seq = load_euroc(data_dir, 0.0, 30.0)
    cal = seq.reference_calibration
    still = load_euroc(data_dir, 0.0, 30.0, gyro_bias_init="standstill")
    speed = np.linalg.norm(seq.truth.v_world_imu_mps, axis=1)
    rot_deg = geodesic_angle_deg(seq.truth.R_world_imu[:-1], seq.truth.R_world_imu[1:]).sum()
    print(f"frames {seq.n_frames} over [{seq.frame_t_s[0]:.3f}, {seq.frame_t_s[-1]:.3f}] s from t0 = "
          f"{raw.t0_abs_s:.7f}; IMU {len(seq.imu.t_s)} samples, spacing "
          f"{np.diff(seq.imu.t_s).min() * 1e3:.3f}-{np.diff(seq.imu.t_s).max() * 1e3:.3f} ms")
    print(f"truth rows within {raw.gt_dt_s.max() * 1e6:.2f} us of the frames; path "
          f"{seq.path_length_m():.2f} m, top speed {speed.max():.2f} m/s, total rotation {rot_deg:.0f} deg")
    print(f"Kalibr cam0: fx fy cx cy = {cal.fx_px[0]} {cal.fy_px[0]} {cal.cx_px[0]} {cal.cy_px[0]} px, "
          f"image {seq.image_size_px}, p_imu_cam = {np.round(cal.p_imu_cam_m[0] * 100, 2)} cm, "
          f"optical axis {np.degrees(np.arccos(cal.R_cam_imu[0, 2, 2])):.2f} deg off +z_imu")
    print(f"IMU noise: {seq.imu_noise}; gravity {seq.gravity_world_mps2} m/s^2")
    print(f"initial gyro bias: truth {np.round(seq.initial_gyro_bias_radps, 5)} rad/s, standstill "
          f"{still.meta['standstill_s']} s mean {np.round(still.initial_gyro_bias_radps, 5)} rad/s "
          f"(difference {np.linalg.norm(still.initial_gyro_bias_radps - seq.initial_gyro_bias_radps) * 1e3:.2f} "
          f"mrad/s); truth accel bias {np.round(raw.gt_accel_bias_mps2[0], 3)} -> "
          f"{np.round(raw.gt_accel_bias_mps2[-1], 3)} m/s^2 over the 30 s")
    tr = seq.tracks
    uv = tr.uv_px[tr.valid]
    W, H = seq.image_size_px
    inside = ((uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)).mean()
    n = tr.n_features
    print(f"triplet features: median {np.median(n):.0f}, min {n.min()}, max {n.max()}; "
          f"{inside * 100:.1f} % of the pixels inside the {W}x{H} image")
    print("features per triplet, frame by frame (triplet ending at frame k, k = 2 ...):")
    for start in range(0, len(n), 40):
        print(f"  {int(tr.frame_index[start]):4d}: " + " ".join(f"{int(c):2d}" for c in n[start:start + 40]))


def filter_figures(data_dir, seeds: list[int], base: FilterConfig, windows=WINDOWS_S, inits=BIAS_INITS) -> None:
    print(f"\nfilter at the Kalibr calibration, {base.max_update_features} features per update, "
          f"min_parallax_m {base.min_parallax_m}, stationary_imu_variance_ratio "
          f"{base.stationary_imu_variance_ratio:g}, bucket seeds {seeds}: median [min, max] over the seeds")
    print(f"{'window':>9} {'gyro bias':>13} {'path m':>7} {'pos RMSE m':>22} {'att RMSE deg':>20} "
          f"{'end err/path %':>16} {'drift m/m':>10} {'diverged':>8}")
    for t_a, t_b in windows:
        for init in inits:
            try:
                seq = load_euroc(data_dir, t_a, t_b, gyro_bias_init=init)
            except EurocDataError:
                continue  # "standstill" on a window that starts in flight
            f, att, end, drift, div = [], [], [], [], 0
            for seed in seeds:
                result = run(seq, seq.reference_calibration, replace(base, bucket_seed=seed))
                f.append(position_rmse_objective(result, seq.truth)[0])
                att.append(pose_errors(result, seq.truth)["attitude_rmse"][0])
                end.append(np.linalg.norm(result.p_world_imu_m[0, -1] - seq.truth.p_world_imu_m[-1])
                           / seq.path_length_m() * 100)
                drift.append(drift_metrics(result.p_world_imu_m, result.R_world_imu, seq.truth)["drift_m_per_m"][0])
                div += int(result.diverged[0])
            def fmt(v, d):
                return f"{np.median(v):.{d}f} [{np.min(v):.{d}f}, {np.max(v):.{d}f}]"
            drift_m_per_m = np.nanmedian(drift) if np.isfinite(drift).any() else np.nan
            print(f"{t_a:4.0f}-{t_b:<4.0f} {init:>13} {seq.path_length_m():7.2f} {fmt(f, 3):>22} "
                  f"{fmt(att, 2):>20} {np.median(end):16.2f} {drift_m_per_m:10.4f} {div:>5}/{len(seeds)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", default=str(DEFAULT_DATA_DIR))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3, 4])
    parser.add_argument("--min-parallax", type=float, default=0.005)
    parser.add_argument("--imu-variance-ratio", type=float, default=1e6)
    args = parser.parse_args()
    loader_facts(args.data_dir)
    base = FilterConfig(min_parallax_m=args.min_parallax, stationary_imu_variance_ratio=args.imu_variance_ratio)
    filter_figures(args.data_dir, args.seeds, base)
    default_ratio = FilterConfig().stationary_imu_variance_ratio
    filter_figures(args.data_dir, args.seeds, replace(base, stationary_imu_variance_ratio=default_ratio),
                   windows=WINDOWS_S[:1], inits=BIAS_INITS[:1])


if __name__ == "__main__":
    main()
