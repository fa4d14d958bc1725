import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from avio.geometry import geodesic_angle_deg
from avio.reference import kitti_2011_10_03_calibration
from avio.sim.simulator import OXTS_IMU_NOISE, SimConfig, SimulatorError, simulate, simulate_world
from avio.sim.trajectory import KINDS, TrajectoryError, ar1, make_trajectory


@pytest.fixture(scope="module")
def noiseless_540m():
    return simulate_world(SimConfig.paper_540m(imu_noise_on=False), seed=11)


def _quat_mul(a, b):
    """Hamilton product of (w, x, y, z) quaternions."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _quat_to_matrix(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _integrate_rk4(imu_t, accel, gyro, gravity, p0, v0, R0):
    """Classical RK4 on (p, v, q) with step 2 dt, so the midpoint is an IMU sample (no
    interpolation): p' = v, v' = R f + g, q' = q (x) [0, w] / 2. Returns p at every second sample."""
    x, y, z, w = Rotation.from_matrix(R0).as_quat()
    q, p, v = np.array([w, x, y, z]), p0.copy(), v0.copy()
    out = [p.copy()]

    def deriv(p, v, q, f, w):
        return v, _quat_to_matrix(q) @ f + gravity, 0.5 * _quat_mul(q, np.r_[0.0, w])

    for i in range(0, len(imu_t) - 2, 2):  # sequential integration in time
        h = imu_t[i + 2] - imu_t[i]
        s = [(accel[i], gyro[i]), (accel[i + 1], gyro[i + 1]), (accel[i + 1], gyro[i + 1]), (accel[i + 2], gyro[i + 2])]
        k1 = deriv(p, v, q, *s[0])
        k2 = deriv(p + h / 2 * k1[0], v + h / 2 * k1[1], q + h / 2 * k1[2], *s[1])
        k3 = deriv(p + h / 2 * k2[0], v + h / 2 * k2[1], q + h / 2 * k2[2], *s[2])
        k4 = deriv(p + h * k3[0], v + h * k3[1], q + h * k3[2], *s[3])
        p = p + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        q = q + h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        q /= np.linalg.norm(q)
        out.append(p.copy())
    return np.array(out), _quat_to_matrix(q)


def test_noiseless_imu_integrates_to_the_truth_over_the_540m_drive(noiseless_540m):
    seq, _ = noiseless_540m
    imu, truth = seq.imu, seq.truth
    p, R_end = _integrate_rk4(imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, seq.gravity_world_mps2,
                              truth.p_world_imu_m[0], truth.v_world_imu_mps[0], truth.R_world_imu[0])
    every = int(round((seq.frame_t_s[1] - seq.frame_t_s[0]) / (imu.t_s[2] - imu.t_s[0])))
    p_frames = p[::every]
    assert len(p_frames) == seq.n_frames
    assert seq.path_length_m() > 500
    assert np.linalg.norm(p_frames - truth.p_world_imu_m, axis=1).max() < 1e-3  # brief: < 1 cm; measured ~1e-6 m
    assert geodesic_angle_deg(R_end, truth.R_world_imu[-1]) < 1e-3


def test_imu_is_specific_force_plus_bias():
    cfg = SimConfig.paper_540m(duration_s=10.0, imu_noise_on=False, accel_bias_mps2=(0.1, -0.2, 0.05),
                               gyro_bias_radps=(1e-3, 2e-3, -3e-3), output="tracks")
    seq, world = simulate_world(cfg, seed=2)
    st = world.trajectory(seq.imu.t_s)
    f = np.einsum("nji,nj->ni", st.R_world_imu, st.a_world_mps2 - seq.gravity_world_mps2)
    np.testing.assert_allclose(seq.imu.accel_imu_mps2 - f, np.tile([0.1, -0.2, 0.05], (len(f), 1)), atol=1e-12)
    np.testing.assert_allclose(seq.imu.gyro_imu_radps - st.omega_imu_radps, np.tile([1e-3, 2e-3, -3e-3], (len(f), 1)),
                               atol=1e-12)
    # At rest-like moments the accelerometer reads +g along body z (z up), like KITTI's OXTS (mean z = +9.79).
    assert np.mean(seq.imu.accel_imu_mps2[:, 2]) == pytest.approx(9.81 + 0.05, abs=0.2)


def test_imu_noise_has_the_discrete_sigma_density_over_sqrt_dt():
    base = SimConfig.paper_540m(duration_s=60.0, max_features=5)
    noisy, world = simulate_world(base, seed=3)
    st = world.trajectory(noisy.imu.t_s)
    f = np.einsum("nji,nj->ni", st.R_world_imu, st.a_world_mps2 - noisy.gravity_world_mps2)
    dt = 0.01
    n_a = noisy.imu.accel_imu_mps2 - f - world.accel_bias_mps2
    n_g = noisy.imu.gyro_imu_radps - st.omega_imu_radps - world.gyro_bias_radps
    assert np.std(n_a) == pytest.approx(base.imu_noise.accel_noise / np.sqrt(dt), rel=0.03)
    assert np.std(n_g) == pytest.approx(base.imu_noise.gyro_noise / np.sqrt(dt), rel=0.03)
    steps = np.diff(world.gyro_bias_radps, axis=0)
    assert np.std(steps) == pytest.approx(base.imu_noise.gyro_bias_walk * np.sqrt(dt), rel=0.03)
    np.testing.assert_allclose(world.accel_bias_mps2[0], noisy.meta["true_accel_bias0_mps2"])


def test_same_seed_gives_the_identical_sequence_and_another_seed_does_not():
    cfg = SimConfig.paper_540m(duration_s=20.0)
    a, b, c = simulate(cfg, 5), simulate(cfg, 5), simulate(cfg, 6)
    assert a.meta["content_hash"] == b.meta["content_hash"] != c.meta["content_hash"]
    np.testing.assert_array_equal(a.imu.accel_imu_mps2, b.imu.accel_imu_mps2)
    np.testing.assert_array_equal(a.tracks.uv_px, b.tracks.uv_px)
    np.testing.assert_array_equal(a.truth.p_world_imu_m, b.truth.p_world_imu_m)
    assert not np.allclose(a.truth.p_world_imu_m, c.truth.p_world_imu_m)
    assert not np.allclose(a.truth_calibration.fx_px, c.truth_calibration.fx_px)


def test_a_noise_seed_keeps_the_world_and_redraws_only_the_measurements():
    cfg = SimConfig.paper_540m(duration_s=20.0)
    a, worlds = simulate(cfg, 5), [simulate_world(cfg, 5, noise_seed=s) for s in ((5, 0, 1), (5, 0, 2))]
    (b, world_b), (c, _) = worlds
    np.testing.assert_array_equal(a.truth.p_world_imu_m, b.truth.p_world_imu_m)  # the same drive
    np.testing.assert_array_equal(a.truth.R_world_imu, b.truth.R_world_imu)
    np.testing.assert_array_equal(simulate_world(cfg, 5)[1].landmarks_world, world_b.landmarks_world)
    for key in ("fx_px", "cx_px", "R_cam_imu", "p_imu_cam_m"):  # and the same camera
        np.testing.assert_array_equal(getattr(a.truth_calibration, key), getattr(b.truth_calibration, key))
    for x, y in ((a, b), (b, c)):  # but other IMU noise and biases, pixel noise and features
        assert not np.allclose(x.imu.gyro_imu_radps, y.imu.gyro_imu_radps)
        assert x.meta["true_gyro_bias0_radps"] != y.meta["true_gyro_bias0_radps"]
        assert not np.array_equal(x.tracks.uv_px, y.tracks.uv_px)
        assert x.meta["content_hash"] != y.meta["content_hash"] and x.name != y.name
    assert b.meta["noise_seed"] == [5, 0, 1] and "noise_seed" not in a.meta
    again = simulate(cfg, 5, noise_seed=(5, 0, 1))
    assert again.meta["content_hash"] == b.meta["content_hash"]
    np.testing.assert_array_equal(again.tracks.uv_px, b.tracks.uv_px)


def test_pixel_noise_per_triplet_is_another_drive_and_absent_from_the_default_hash():
    cfg = SimConfig.paper_540m(duration_s=20.0)
    a, b = simulate(cfg, 5), simulate(replace(cfg, pixel_noise_per_triplet=True), 5)
    np.testing.assert_array_equal(a.imu.gyro_imu_radps, b.imu.gyro_imu_radps)
    assert not np.array_equal(a.tracks.uv_px, b.tracks.uv_px)
    assert a.meta["content_hash"] != b.meta["content_hash"]
    # the default leaves the field out of the hashed config: existing drives keep their hashes
    assert "pixel_noise_per_triplet" not in a.meta["config"] and b.meta["config"]["pixel_noise_per_triplet"]


def test_camera_settings_do_not_change_the_trajectory_or_the_imu():
    cfg = SimConfig.paper_540m(duration_s=20.0)
    a, b = simulate(cfg, 5), simulate(replace(cfg, pixel_noise_px=2.0, max_features=10), 5)
    np.testing.assert_array_equal(a.imu.gyro_imu_radps, b.imu.gyro_imu_radps)
    np.testing.assert_array_equal(a.truth.R_world_imu, b.truth.R_world_imu)
    assert a.tracks.uv_px.shape[1] == 30 and b.tracks.uv_px.shape[1] == 10


def test_speed_ar1_gives_the_bits_of_scipy_lfilter():
    from scipy.signal import lfilter  # the filter the written-out AR(1) replaces (an import of ~0.4 s)

    for seed in range(20):
        x = np.r_[0.0, np.random.default_rng(seed).standard_normal(400)]
        for phi in (0.9, 0.5, -0.3):
            assert np.array_equal(ar1(x, phi), lfilter([np.sqrt(1 - phi * phi)], [1.0, -phi], x))


def test_straight_drive_has_zero_yaw_rate():
    seq = simulate(SimConfig(trajectory="straight", duration_s=30.0, speed_mps=8.0, imu_noise_on=False), 1)
    assert np.abs(seq.imu.gyro_imu_radps).max() < 1e-12
    assert np.abs(seq.truth.p_world_imu_m[:, 1:]).max() < 1e-9
    speed = np.linalg.norm(seq.truth.v_world_imu_mps, axis=1)
    np.testing.assert_allclose(speed, 8.0, rtol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_trajectory_rates_match_finite_differences(kind):
    traj = make_trajectory(kind, 40.0, 8.0, seed=9)
    t = np.linspace(0.5, 39.5, 60)
    h = 1e-4
    a, b, c = traj(t - h), traj(t + h), traj(t)
    np.testing.assert_allclose((b.p_world_imu_m - a.p_world_imu_m) / (2 * h), c.v_world_imu_mps, atol=1e-6)
    np.testing.assert_allclose((b.v_world_imu_mps - a.v_world_imu_mps) / (2 * h), c.a_world_mps2, atol=1e-5)
    R_rel = np.einsum("nji,njk->nik", a.R_world_imu, b.R_world_imu)
    np.testing.assert_allclose(Rotation.from_matrix(R_rel).as_rotvec() / (2 * h), c.omega_imu_radps, atol=1e-6)
    # Car-like: the body x axis points along the velocity wherever the car moves.
    speed = np.linalg.norm(c.v_world_imu_mps, axis=1)
    moving = speed > 0.1
    cos = np.einsum("ni,ni->n", c.R_world_imu[moving, :, 0], c.v_world_imu_mps[moving]) / speed[moving]
    assert np.all(cos > 1 - 1e-9)


def test_city_is_flat_and_hills_and_full3d_pitch_and_roll():
    t = np.linspace(0, 100, 2001)
    euler = {k: Rotation.from_matrix(make_trajectory(k, 100.0, 8.0, 2)(t).R_world_imu).as_euler("ZYX", degrees=True)
             for k in ("city", "city_hills", "full3d")}
    assert np.abs(euler["city"][:, 1:]).max() < 1e-9
    assert 0.5 < np.abs(euler["city_hills"][:, 1]).max() < np.abs(euler["full3d"][:, 1]).max()
    assert 0.5 < np.abs(euler["city_hills"][:, 2]).max() < np.abs(euler["full3d"][:, 2]).max()
    heading_change = np.degrees(np.abs(np.diff(np.unwrap(np.radians(euler["city"][:, 0])))).sum())
    assert heading_change > 180, "a city drive turns corners"


def test_city_drive_stops():
    traj = make_trajectory("city", 78.0, 7.0, seed=1)
    speed = np.linalg.norm(traj(np.linspace(0, 78, 7801)).v_world_imu_mps, axis=1)
    assert (speed < 1e-9).sum() >= 100  # at least ~1 s at rest
    assert speed.max() < 15.0


@pytest.mark.parametrize(
    "preset, length_m, duration_s",
    [(SimConfig.paper_540m, 540.0, 78.0), (SimConfig.paper_928m, 928.0, 115.0)],
)
def test_presets_have_the_paper_lengths_and_durations(preset, length_m, duration_s):
    seq = simulate(preset(max_features=5), seed=0)
    assert seq.path_length_m() == pytest.approx(length_m, rel=0.02)
    assert seq.frame_t_s[-1] - seq.frame_t_s[0] == pytest.approx(duration_s, rel=0.02)
    assert seq.imu.t_s[0] <= seq.frame_t_s[0] and seq.imu.t_s[-1] >= seq.frame_t_s[-1]
    np.testing.assert_allclose(np.diff(seq.imu.t_s), 0.01)


def test_tracks_per_triplet_around_max_features():
    seq = simulate(SimConfig.paper_540m(), seed=4)
    n = seq.tracks.n_features
    assert seq.tracks.uv_px.shape == (seq.n_frames - 2, 30, 3, 2)
    assert np.median(n) == 30 and np.mean(n >= 25) > 0.95
    np.testing.assert_array_equal(seq.tracks.frame_index, np.arange(2, seq.n_frames))


def test_simulating_the_540m_drive_with_tracks_is_fast():
    simulate(SimConfig.paper_540m(duration_s=5.0), 0)  # warm imports
    t0 = time.perf_counter()
    simulate(SimConfig.paper_540m(), 0)
    assert time.perf_counter() - t0 < 3.0  # ~0.5 s on one core; headroom for a loaded CI machine


def test_truth_calibration_errors():
    ref = kitti_2011_10_03_calibration()
    real = simulate(SimConfig.paper_540m(duration_s=5.0), 8).truth_calibration
    assert geodesic_angle_deg(ref.R_cam_imu[0], real.R_cam_imu[0]) == pytest.approx(0.4, abs=1e-6)
    assert np.linalg.norm(real.p_imu_cam_m - ref.p_imu_cam_m) == pytest.approx(0.03, abs=1e-9)
    assert 0 < abs(real.fx_px[0] - ref.fx_px[0]) < 6 and 0 < abs(real.cy_px[0] - ref.cy_px[0]) < 6

    none = simulate(SimConfig.paper_540m(duration_s=5.0, calibration_error="none"), 8)
    for name in ("fx_px", "cy_px", "R_cam_imu", "p_imu_cam_m", "time_offset_s"):
        np.testing.assert_array_equal(getattr(none.truth_calibration, name), getattr(ref, name))

    delta = (2.0, -1.0, 0.5, 3.0, 0.0, 0.0, 1.0, 0.01, 0.0, -0.02)
    cfg = SimConfig.paper_540m(duration_s=5.0, calibration_error="explicit", calibration_delta=delta, time_offset_s=0.02)
    ex = simulate(cfg, 8).truth_calibration
    assert ex.fx_px[0] - ref.fx_px[0] == pytest.approx(2.0) and ex.cy_px[0] - ref.cy_px[0] == pytest.approx(3.0)
    assert geodesic_angle_deg(ref.R_cam_imu[0], ex.R_cam_imu[0]) == pytest.approx(1.0)
    np.testing.assert_allclose(ex.p_imu_cam_m[0] - ref.p_imu_cam_m[0], [0.01, 0.0, -0.02])
    assert ex.time_offset_s[0] == 0.02


def test_meta_is_json_and_names_config_seed_and_hash():
    seq = simulate(SimConfig.paper_540m(duration_s=5.0), 3)
    meta = json.loads(json.dumps(seq.meta))
    assert meta["seed"] == 3 and meta["config"]["trajectory"] == "city" and len(meta["content_hash"]) == 64
    assert seq.reference_calibration is not None and seq.imu_noise == SimConfig().imu_noise == OXTS_IMU_NOISE


def test_images_output_renders_every_frame_once(tmp_path):
    cfg = SimConfig.paper_540m(duration_s=1.0, output="images")
    seq = simulate(cfg, 2, image_dir=tmp_path)
    assert seq.tracks is None and len(seq.image_paths) == seq.n_frames == 11
    mtimes = [Path(p).stat().st_mtime_ns for p in seq.image_paths]
    again = simulate(cfg, 2, image_dir=tmp_path)
    assert again.image_paths == seq.image_paths
    assert [Path(p).stat().st_mtime_ns for p in again.image_paths] == mtimes
    with pytest.raises(SimulatorError, match="image_dir"):
        simulate(cfg, 2)


@pytest.mark.parametrize(
    "overrides, field",
    [
        ({"trajectory": "moon"}, "trajectory"),
        ({"outlier_fraction": 2.0}, "outlier_fraction"),
        ({"calibration_error": "explicit"}, "calibration_delta"),
        ({"output": "video"}, "output"),
        ({"camera_rate_hz": 200.0}, "camera_rate_hz"),
    ],
)
def test_bad_config_names_the_field(overrides, field):
    with pytest.raises(SimulatorError, match=f"SimConfig.{field}"):
        simulate(SimConfig(**overrides), 0)


def test_trajectory_rejects_times_outside_its_domain():
    traj = make_trajectory("city", 10.0, 5.0, 0)
    with pytest.raises(TrajectoryError, match="outside the trajectory domain"):
        traj(np.array([0.0, 13.0]))
    with pytest.raises(TrajectoryError, match="too short"):
        make_trajectory("city", 5.0, 5.0, 0, n_stops=2)
