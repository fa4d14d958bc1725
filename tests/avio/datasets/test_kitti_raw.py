"""KITTI raw loader/writer and OXTS conversion: real 2011_09_26 files, and a simulator round trip."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from avio.datasets.kitti_raw import KittiRawError, cam0_imu_transform, load_kitti_raw, write_kitti_raw
from avio.datasets.oxts import (
    F,
    OxtsError,
    latlon_to_mercator,
    mercator_scale,
    mercator_to_latlon,
    oxts_enu_states,
    oxts_to_poses,
    read_oxts_packets,
)
from avio.geometry import geodesic_angle_deg
from avio.sim.simulator import SimConfig, simulate

DRIVE = "2011_09_26_drive_0001_sync"


@pytest.fixture(scope="module")
def raw_dir(shared_data: Path, skip_no_data) -> Path:
    path = shared_data / "kitti_raw_2011_09_26_drive_0001"
    if not (path / DRIVE / "oxts" / "data").is_dir():
        skip_no_data(f"{path} lacks the OXTS packets")
    return path


@pytest.fixture(scope="module")
def real(raw_dir):
    return load_kitti_raw(raw_dir / DRIVE)


@pytest.fixture
def raw_copy(raw_dir, tmp_path) -> Path:
    """A writable copy of the real drive (108 tiny packets and the calib files)."""
    dst = tmp_path / "2011_09_26"
    shutil.copytree(raw_dir, dst)
    return dst


# ---------------------------------------------------------------- real data


@pytest.mark.data
def test_real_path_length_matches_integrated_oxts_speed(real, raw_dir):
    p, v, t = real.truth.p_world_imu_m, real.truth.v_world_imu_mps, real.frame_t_s
    length = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum()
    assert 100.0 < length < 115.0
    packets = read_oxts_packets(raw_dir / DRIVE / "oxts" / "data")
    for speed in (np.hypot(v[:, 0], v[:, 1]), np.hypot(packets[:, F["vf"]], packets[:, F["vl"]])):
        assert abs(np.trapezoid(speed, t) / length - 1.0) < 0.01


@pytest.mark.data
def test_real_path_and_heading_match_integrated_oxts_velocity(real):
    p, v, t = real.truth.p_world_imu_m, real.truth.v_world_imu_mps, real.frame_t_s
    p_from_v = cumulative_trapezoid(v, t, axis=0, initial=0.0)
    length = np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
    assert np.linalg.norm(p_from_v - p, axis=1).max() < 0.01 * length
    # Heading change over the drive: course of 1-s chords of the positions and of the
    # integrated velocities (ve, vn); the car turns ~8 deg and both agree to within 1 deg.
    def chord(q):
        return np.unwrap(np.arctan2(q[10:, 1] - q[:-10, 1], q[10:, 0] - q[:-10, 0]))
    turn_p, turn_v = np.degrees(chord(p)[-1] - chord(p)[0]), np.degrees(chord(p_from_v)[-1] - chord(p_from_v)[0])
    assert -10.0 < turn_p < -6.0
    assert abs(turn_p - turn_v) < 1.0


@pytest.mark.data
def test_real_imu_is_10hz_specific_force_with_gravity(real):
    dt = np.diff(real.imu.t_s)
    assert 0.09 < np.median(dt) < 0.11
    # Specific force rotated to the gravity-aligned world: +g up on average (the car is level).
    f_world = np.einsum("nij,nj->ni", real.truth.R_world_imu, real.imu.accel_imu_mps2)
    assert abs(f_world[:, 2].mean() - 9.81) < 0.1


@pytest.mark.data
def test_enu_states_agree_with_the_devkit_poses(real, raw_dir):
    packets = read_oxts_packets(raw_dir / DRIVE / "oxts" / "data")
    T = oxts_to_poses(packets)
    p, R, _ = oxts_enu_states(packets)
    np.testing.assert_allclose(T[:, :3, :3], np.swapaxes(R[0], 0, 1) @ R, atol=1e-12)
    np.testing.assert_allclose(T[:, :3, 3], (p - p[0]) @ R[0], atol=1e-9)
    np.testing.assert_allclose(T[0], np.eye(4), atol=1e-8)  # inverse of ~5e6 m coordinates


@pytest.mark.data
def test_real_calibration_composes_the_three_files(real, raw_dir):
    cal = real.reference_calibration
    assert (cal.fx_px[0], cal.cx_px[0], cal.cy_px[0]) == (721.5377, 609.5593, 172.854)
    assert real.image_size_px == (1242, 375)
    R_rect, t_rect = cam0_imu_transform(raw_dir, rectified=True)
    R_raw, t_raw = cam0_imu_transform(raw_dir, rectified=False)
    # R_rect_00 of 2011_09_26 is a 0.75 deg rotation; the camera origin is the same point.
    assert geodesic_angle_deg(R_raw, R_rect) == pytest.approx(0.75, abs=0.01)
    np.testing.assert_allclose(-R_rect.T @ t_rect, -R_raw.T @ t_raw, atol=1e-6)
    np.testing.assert_allclose(cal.p_imu_cam_m[0], -R_rect.T @ t_rect)
    # The camera sits ~1.1 m ahead of and ~0.7 m above the OXTS unit, and looks forward.
    assert 1.0 < cal.p_imu_cam_m[0, 0] < 1.2 and 0.6 < cal.p_imu_cam_m[0, 2] < 0.8
    np.testing.assert_allclose(R_rect @ [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], atol=0.02)


@pytest.mark.data
def test_real_image_timestamps_are_kept(real):
    assert len(real.meta["image_00_t_s"]) == 6  # the shared copy is truncated to 6 lines
    assert abs(real.meta["image_00_t_s"][0] - real.frame_t_s[0]) < 0.01
    assert real.image_paths is None


@pytest.mark.data
@pytest.mark.parametrize("edit, match", [
    (lambda d: (d / DRIVE / "oxts" / "data" / "0000000007.txt").write_text("1 2 3\n"),
     r"0000000007\.txt:1: expected 30 numbers, got 3"),
    (lambda d: (d / DRIVE / "oxts" / "data" / "0000000009.txt").unlink(),
     r"timestamps\.txt: 108 timestamps for 107 packets"),
    (lambda d: _replace_line(d / DRIVE / "oxts" / "timestamps.txt", 5, "2011-09-26 13:02:25.000000000"),
     r"timestamps\.txt:5: timestamp does not increase"),
    (lambda d: _replace_line(d / DRIVE / "oxts" / "timestamps.txt", 3, "yesterday"),
     r"timestamps\.txt:3: not a timestamp"),
    (lambda d: _replace_line(d / "calib_velo_to_cam.txt", 2, "R 1 0 0"),
     r"calib_velo_to_cam\.txt:2: expected 'key: values'"),
    (lambda d: _replace_line(d / "calib_imu_to_velo.txt", 3, "T: 1 2"),
     r"calib_imu_to_velo\.txt: T has 2 numbers, expected 3"),
    (lambda d: (d / "calib_cam_to_cam.txt").unlink(), r"calib_cam_to_cam\.txt: file not found"),
    (lambda d: shutil.rmtree(d / DRIVE / "oxts" / "data"), r"no OXTS packet files"),
])
def test_broken_raw_files_are_named(raw_copy, edit, match):
    edit(raw_copy)
    with pytest.raises((KittiRawError, OxtsError), match=match):
        load_kitti_raw(raw_copy / DRIVE)


def _replace_line(path: Path, line_no: int, text: str) -> None:
    lines = path.read_text().splitlines(keepends=True)
    lines[line_no - 1] = text + "\n"
    path.write_text("".join(lines))


# ---------------------------------------------------------------- synthetic


def test_mercator_round_trip_and_local_metric_scale():
    lat0, lon0 = 49.0, 8.4
    s = mercator_scale(lat0)
    lat = lat0 + np.array([0.0, 1e-3, -2e-3])
    lon = lon0 + np.array([0.0, 2e-3, 1e-3])
    mx, my = latlon_to_mercator(lat, lon, s)
    np.testing.assert_allclose(np.stack(mercator_to_latlon(mx, my, s)), np.stack([lat, lon]), atol=1e-12)
    # 1e-3 deg of latitude is 111.3 m on the ground; the devkit's scaled Mercator agrees to 1e-4.
    assert (my[1] - my[0]) == pytest.approx(np.radians(1e-3) * 6378137.0, rel=1e-4)


@pytest.fixture(scope="module")
def simulated():
    return simulate(SimConfig(trajectory="full3d", duration_s=15.0, output="tracks", imu_noise_on=False), seed=11)


def test_simulated_sequence_round_trips_through_the_files(simulated, tmp_path):
    drive_dir = write_kitti_raw(simulated, tmp_path)
    assert drive_dir == tmp_path / "2011_09_26" / "2011_09_26_drive_0001_sync"
    back = load_kitti_raw(drive_dir)
    np.testing.assert_allclose(back.frame_t_s, simulated.frame_t_s, atol=1e-9)
    gt, gt0 = back.truth, simulated.truth
    np.testing.assert_allclose(gt.p_world_imu_m, gt0.p_world_imu_m - gt0.p_world_imu_m[0], atol=1e-6)
    assert geodesic_angle_deg(gt.R_world_imu, gt0.R_world_imu).max() < 1e-9
    np.testing.assert_allclose(gt.v_world_imu_mps, gt0.v_world_imu_mps, atol=1e-12)
    # IMU at the frame times (10 Hz, as real synced OXTS), interpolated from the 100 Hz record.
    i = np.searchsorted(simulated.imu.t_s, simulated.frame_t_s)
    np.testing.assert_allclose(back.imu.t_s, simulated.frame_t_s, atol=1e-9)
    np.testing.assert_allclose(back.imu.accel_imu_mps2, simulated.imu.accel_imu_mps2[i], atol=1e-9)
    np.testing.assert_allclose(back.imu.gyro_imu_radps, simulated.imu.gyro_imu_radps[i], atol=1e-9)
    ref, ref0 = back.reference_calibration, simulated.reference_calibration
    for name in ("fx_px", "fy_px", "cx_px", "cy_px", "R_cam_imu", "p_imu_cam_m"):
        np.testing.assert_allclose(getattr(ref, name), getattr(ref0, name), atol=1e-10)
    assert back.image_size_px == simulated.image_size_px


def test_written_level_frame_fields_are_consistent(simulated, tmp_path):
    packets = read_oxts_packets(write_kitti_raw(simulated, tmp_path) / "oxts" / "data")
    speed = np.hypot(packets[:, F["ve"]], packets[:, F["vn"]])
    np.testing.assert_allclose(np.hypot(packets[:, F["vf"]], packets[:, F["vl"]]), speed, atol=1e-9)
    # A car does not slide sideways much: the leftward velocity is small against the forward one.
    assert np.abs(packets[:, F["vl"]]).max() < 0.1 * speed.max()
    # Upward rate in the level frame = world z rate = yaw rate d(yaw)/dt + roll rate x sin(pitch).
    gyro_world = np.einsum("nij,nj->ni", simulated.truth.R_world_imu, packets[:, [F["wx"], F["wy"], F["wz"]]])
    np.testing.assert_allclose(packets[:, F["wu"]], gyro_world[:, 2], atol=1e-12)
    yaw_rate = np.gradient(np.unwrap(packets[:, F["yaw"]]), simulated.frame_t_s)
    assert np.abs(yaw_rate).max() > 0.1  # the drive turns, so the check has teeth
    np.testing.assert_allclose(packets[2:-2, F["wu"]], yaw_rate[2:-2], atol=0.02)


def test_writer_refuses_times_outside_one_day(simulated, tmp_path):
    from dataclasses import replace

    late = replace(simulated, frame_t_s=simulated.frame_t_s + 86400.0)
    with pytest.raises(KittiRawError, match="within one day"):
        write_kitti_raw(late, tmp_path)
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_rendered_images_round_trip_and_are_found(tmp_path):
    seq = simulate(SimConfig(duration_s=1.0, output="images"), seed=5, image_dir=tmp_path / "render")
    back = load_kitti_raw(write_kitti_raw(seq, tmp_path / "raw"))
    assert len(back.image_paths) == seq.n_frames
    assert Path(back.image_paths[3]).read_bytes() == Path(seq.image_paths[3]).read_bytes()


def test_content_hash_follows_content_not_location(simulated, tmp_path):
    a = load_kitti_raw(write_kitti_raw(simulated, tmp_path / "a"))
    b = load_kitti_raw(write_kitti_raw(simulated, tmp_path / "b"))
    c = load_kitti_raw(write_kitti_raw(simulated, tmp_path / "b"), rectified=False)
    assert a.meta["content_hash"] == b.meta["content_hash"] != c.meta["content_hash"]


@pytest.mark.data
def test_real_level_frame_fields_and_the_vl_sign_quirk(raw_dir):
    from scipy.spatial.transform import Rotation

    packets = read_oxts_packets(raw_dir / DRIVE / "oxts" / "data")
    _, R, v = oxts_enu_states(packets)
    R_level = Rotation.from_euler("Z", packets[:, [F["yaw"]]]).as_matrix()
    def level(b):
        return np.einsum("nji,nj->ni", R_level, np.einsum("nij,nj->ni", R, b))
    a = level(packets[:, [F["ax"], F["ay"], F["az"]]])
    np.testing.assert_allclose(a, packets[:, [F["af"], F["al"], F["au"]]], atol=0.03)
    w = level(packets[:, [F["wx"], F["wy"], F["wz"]]])
    np.testing.assert_allclose(w, packets[:, [F["wf"], F["wl"], F["wu"]]], atol=1e-4)
    v_level = np.einsum("nji,nj->ni", R_level, v)
    np.testing.assert_allclose(v_level[:, 0], packets[:, F["vf"]], atol=1e-3)
    # vl is the rightward, not leftward, component in these files (documented in avio.datasets.oxts).
    np.testing.assert_allclose(v_level[:, 1], -packets[:, F["vl"]], atol=0.05)
