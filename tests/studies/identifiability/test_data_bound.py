"""studies/identifiability/data_bound.py and drive_model.py: the data's Cramér–Rao bound from the
simulator's own model.

The model's residuals vanish at the truth (its pixels are the simulator's, its IMU residual is the
Euler step's error alone); the sparse Schur complement is the dense inverse's; and the physics of
the two rigs comes out: planar motion leaves the lever arm along its rotation axis (dz) free and
the 6-DoF drive does not."""

from __future__ import annotations

import numpy as np
import pytest

from avio.sim.camera import project_landmarks
from avio.sim.simulator import SimConfig, simulate_world


def _drive(rig: str, seconds: float, **overrides):
    return simulate_world(getattr(SimConfig, rig)(duration_s=seconds, **overrides), (0, 100))


@pytest.mark.parametrize("rig", ["paper_540m", "full3d_540m"])
def test_the_models_pixels_are_the_simulators_and_its_imu_residual_is_the_euler_steps_error(load_script, rig):
    module = load_script("drive_model")
    seq, world = _drive(rig, 6.0, imu_noise_on=False)
    frame, lm, _, _ = module.drive_observations(seq, world)  # also checks the re-drawn tracks against the sequence's
    c, n = seq.truth_calibration, len(frame)
    st = world.trajectory(seq.frame_t_s)
    uv = module.project(st.R_world_imu[frame], st.p_world_imu_m[frame], world.landmarks_world[lm],
                        np.full(n, c.fx_px[0]), np.full(n, c.fy_px[0]), np.full(n, c.cx_px[0]), np.full(n, c.cy_px[0]),
                        np.broadcast_to(c.R_cam_imu[0], (n, 3, 3)), np.broadcast_to(c.p_imu_cam_m[0], (n, 3)))
    obs = project_landmarks(world.trajectory, seq.frame_t_s, c, world.landmarks_world, seq.image_size_px, 1.0, 80.0)
    noiseless = dict(zip(zip(obs.frame_index.tolist(), obs.landmark_id.tolist()), obs.uv_px))
    np.testing.assert_allclose(uv, [noiseless[k] for k in zip(frame.tolist(), lm.tolist())], atol=1e-9)

    at = np.searchsorted(seq.imu.t_s, seq.frame_t_s - 1e-9)
    idx = at[:-1, None] + np.arange(at[1] - at[0])
    truth = (st.R_world_imu[:-1], st.p_world_imu_m[:-1], st.v_world_imu_mps[:-1], world.accel_bias_mps2[at][:-1],
             world.gyro_bias_radps[at][:-1], st.R_world_imu[1:], st.p_world_imu_m[1:], st.v_world_imu_mps[1:])
    m = len(idx)
    r = module.imu_residual(truth, np.zeros((m, 15)), np.zeros((m, 9)), seq.imu.gyro_imu_radps[idx],
                            seq.imu.accel_imu_mps2[idx], 0.01, seq.gravity_world_mps2)
    # a wrong frame, sign or gravity would leave ~0.1 rad, ~1 m/s, ~0.1 m; the Euler step leaves this
    assert np.abs(r[:, :3]).max() < 1e-3 and np.abs(r[:, 3:6]).max() < 5e-3 and np.abs(r[:, 6:]).max() < 5e-4


def _space(rig: str, seconds: float):
    from bench.problems.synthetic import Synthetic

    problem = Synthetic(drives=[rig], holdout=None, data_seed=0, space="local", sim={"duration_s": seconds})
    return problem.calibration_space.decode, problem.truth, problem.sequence.truth_calibration


@pytest.mark.parametrize("triplets", [False, True])
def test_points_eliminated_by_qr_and_the_sparse_schur_complement_give_the_dense_inverses_calibration_block(
        load_script, triplets):
    module = load_script("data_bound")
    decode, x_truth, true_cal = _space("full3d_540m", 3.0)
    seq, world = simulate_world(SimConfig.full3d_540m(duration_s=3.0), (0, 100), true_calibration=true_cal)
    pixels = module.Pixels(triplets=triplets)
    J, n_x = module.drive_jacobian(seq, world, decode, x_truth, pixels, points=True)[:2]
    assert n_x > module.STATE * len(seq.frame_t_s)  # the points are columns here
    dense = np.linalg.inv(np.linalg.inv((J.T @ J).toarray())[n_x:, n_x:])
    tolerance = {"rtol": 1e-6, "atol": 1e-6 * np.abs(dense).max()}
    np.testing.assert_allclose(module.calibration_information(J, n_x), dense, **tolerance)
    projected = module.drive_information(seq, world, decode, x_truth, pixels)  # the points by their QR instead
    np.testing.assert_allclose(projected, dense, **tolerance)


def test_planar_motion_leaves_the_lever_arm_along_its_rotation_axis_free_and_the_6dof_drive_does_not(load_script):
    module = load_script("data_bound")
    sigma = {}
    for rig in ("paper_540m", "full3d_540m"):
        decode, x_truth, true_cal = _space(rig, 30.0)
        seq, world = simulate_world(getattr(SimConfig, rig)(duration_s=30.0), (0, 100), true_calibration=true_cal)
        info = module.drive_information(seq, world, decode, x_truth)
        rest = info[:9, :9]
        dz_given_rest = info[9, 9] - info[9, :9] @ np.linalg.solve(rest, info[:9, 9])  # 1/m^2
        sigma[rig] = dict(zip(module.VARS10[:9], np.sqrt(np.diag(np.linalg.inv(rest)))), dz=dz_given_rest ** -0.5
                          if dz_given_rest > 0 else np.inf)
    assert sigma["paper_540m"]["dz"] > 1.0  # metres: flat, rotation about the vertical alone
    assert sigma["full3d_540m"]["dz"] < 0.1
    for rig in sigma:  # the rest of the lever arm and the rotation are determined on both (dz at the truth)
        assert sigma[rig]["dx"] < 0.1 and max(sigma[rig][v] for v in ("rx", "ry", "rz")) < 0.5


def test_a_variable_without_information_is_named_undetermined_and_a_weak_one_is_not(load_script):
    module = load_script("data_bound")
    info = np.diag([1e2, 2.6e-2, 1e2, 1e2, 1e4, 4e2, 1e4, 7e3, 5e3, 1e-6])  # the flat city's scales: fy weak, dz none
    info[9, 9] = -1e-6  # a zero measured by subtraction may come out negative
    A, free = np.eye(10), list(module.VARS10)
    assert module.undetermined(info, free, A) == ["dz"]
    info[9, 9] = 50.0
    assert module.undetermined(info, free, A) == []


def test_the_linearised_ml_estimate_scatters_as_the_bound_says_on_the_simulators_own_noise(load_script):
    # 30 noise realisations of a 5 s excited drive: one Gauss-Newton step from the truth on each one's pixels,
    # IMU and bias walks; a model noise off by a factor (pixel noise per triplet, a sample rate's sqrt) moves
    # tr(I C)/10 far from 1 (its sampling scatter here ~0.08)
    module = load_script("data_bound")
    out = module.check("full3d_540m", 0, 30, 5.0)
    assert 0.75 < out["trace"] < 1.3, out
    assert np.all(np.abs(out["t"]) < 4.0), out  # no bias either
