"""KITTI raw layout: a synced drive folder and its date's calib files, read into a Sequence
and written back from one (so that simulated sequences round-trip through the files).

Layout (``<date>/`` holds the three calib files and ``<date>_drive_<nnnn>_sync/``)::

    calib_cam_to_cam.txt  calib_imu_to_velo.txt  calib_velo_to_cam.txt
    <drive>_sync/oxts/data/0000000000.txt ...  oxts/timestamps.txt
    <drive>_sync/image_00/data/0000000000.png ...  image_00/timestamps.txt

What the loader does:
- Truth = the OXTS pose and velocity at each synced frame, in a gravity-aligned ENU world
  (x east, y north, z up; origin at the first packet), see ``avio.datasets.oxts``.
- IMU = the OXTS body specific force (ax, ay, az; gravity included) and rates (wx, wy, wz) of
  the same packets. The *synced* OXTS is 10 Hz only, so this IMU is 10 Hz: usable for tests and
  coarse runs, not a substitute for the 100 Hz ``oxts`` of the unsynced "extract" data.
- Frame times = the OXTS timestamps (seconds since midnight of the first one), since truth and
  IMU are sampled there; the image_00 stamps are a few ms off and are kept in ``meta``.
- Calibration: ``T_cam0_imu = [R_rect_00] · T_cam_velo · T_velo_imu`` (rectified or not), and
  intrinsics from ``P_rect_00`` (the synced images are rectified either way).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from avio.calibration import Calibration
from avio.datasets.kitti00 import KittiDataError
from avio.datasets.oxts import (
    F,
    OxtsError,
    format_timestamps,
    oxts_enu_states,
    packets_from_states,
    read_oxts_packets,
    read_timestamps,
)
from avio.sequence import GroundTruth, ImuSamples, Sequence, content_hash

CALIB_FILES = ("calib_cam_to_cam.txt", "calib_imu_to_velo.txt", "calib_velo_to_cam.txt")


class KittiRawError(KittiDataError):
    """A KITTI raw drive or calib folder is missing something or is inconsistent."""


def read_calib_file(path: str | Path) -> dict[str, np.ndarray]:
    """``{key: values}`` of a KITTI calib text file (``key: v1 v2 ...``); non-numeric entries
    (``calib_time``) are skipped. KittiRawError naming the line for a line without ``:``."""
    path = Path(path)
    if not path.is_file():
        raise KittiRawError(f"{path}: file not found")
    out = {}
    with open(path) as handle:
        for line_no, line in enumerate(handle, start=1):
            if not line.strip():
                continue
            key, sep, rest = line.partition(":")
            if not sep:
                raise KittiRawError(f"{path}:{line_no}: expected 'key: values', got {line.strip()[:60]!r}")
            try:
                out[key.strip()] = np.array([float(x) for x in rest.split()])
            except ValueError:
                if key.strip() != "calib_time":
                    raise KittiRawError(f"{path}:{line_no}: {key.strip()} is not numeric") from None
    return out


def _entry(calib: dict, key: str, size: int, path: Path) -> np.ndarray:
    if key not in calib:
        raise KittiRawError(f"{path}: no entry {key!r}")
    if calib[key].size != size:
        raise KittiRawError(f"{path}: {key} has {calib[key].size} numbers, expected {size}")
    return calib[key]


def cam0_imu_transform(calib_dir: str | Path, rectified: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``(R_cam_imu (3,3), t_cam_imu_m (3,))`` of cam0: ``x_cam = R x_imu + t``, composed from
    calib_imu_to_velo, calib_velo_to_cam and (if ``rectified``) R_rect_00 of calib_cam_to_cam."""
    calib_dir = Path(calib_dir)
    parts = []
    for name in ("calib_imu_to_velo.txt", "calib_velo_to_cam.txt"):
        c = read_calib_file(calib_dir / name)
        parts.append((_entry(c, "R", 9, calib_dir / name).reshape(3, 3), _entry(c, "T", 3, calib_dir / name)))
    (R_vi, t_vi), (R_cv, t_cv) = parts
    R, t = R_cv @ R_vi, R_cv @ t_vi + t_cv
    if rectified:
        path = calib_dir / "calib_cam_to_cam.txt"
        R_rect = _entry(read_calib_file(path), "R_rect_00", 9, path).reshape(3, 3)
        R, t = R_rect @ R, R_rect @ t
    return R, t


def reference_calibration(calib_dir: str | Path, rectified: bool = True) -> tuple[Calibration, tuple[int, int]]:
    """(Calibration batch of 1 with P_rect_00 intrinsics and the cam0–IMU extrinsic,
    rectified image size (width, height) from S_rect_00)."""
    path = Path(calib_dir) / "calib_cam_to_cam.txt"
    c = read_calib_file(path)
    P = _entry(c, "P_rect_00", 12, path).reshape(3, 4)
    w, h = _entry(c, "S_rect_00", 2, path)
    R, t = cam0_imu_transform(calib_dir, rectified)
    cal = Calibration.single(P[0, 0], P[1, 1], P[0, 2], P[1, 2], R, -R.T @ t)
    return cal, (int(round(w)), int(round(h)))


def load_kitti_raw(
    drive_dir: str | Path, calib_dir: str | Path | None = None, rectified: bool = True
) -> Sequence:
    """A synced KITTI raw drive as a Sequence (tracks None until the front end runs).

    drive_dir: ``.../<date>_drive_<nnnn>_sync``; calib_dir: the folder of the three calib files
    (default: the drive folder's parent, as in the KITTI layout). ``rectified`` chooses the
    rectified or unrectified cam0 extrinsic; see the module doc for frames and clocks.
    """
    drive_dir = Path(drive_dir)
    calib_dir = drive_dir.parent if calib_dir is None else Path(calib_dir)
    if not drive_dir.is_dir():
        raise KittiRawError(f"{drive_dir}: drive folder not found")
    packets = read_oxts_packets(drive_dir / "oxts" / "data")
    t, midnight = read_timestamps(drive_dir / "oxts" / "timestamps.txt")
    if len(t) != len(packets):
        raise KittiRawError(
            f"{drive_dir / 'oxts' / 'timestamps.txt'}: {len(t)} timestamps for {len(packets)} packets"
        )
    cal, size = reference_calibration(calib_dir, rectified)
    p, R, v = oxts_enu_states(packets)
    imu = ImuSamples(t, packets[:, [F["ax"], F["ay"], F["az"]]], packets[:, [F["wx"], F["wy"], F["wz"]]])
    images = sorted((drive_dir / "image_00" / "data").glob("*.png"))
    if images and len(images) != len(t):
        raise KittiRawError(f"{drive_dir / 'image_00' / 'data'}: {len(images)} images for {len(t)} OXTS packets")
    meta = {"source": "kitti_raw", "drive_dir": str(drive_dir), "calib_dir": str(calib_dir),
            "rectified_extrinsic": rectified, "date_midnight": str(midnight),
            "origin_lat_lon_alt": packets[0, :3].tolist()}
    stamps = drive_dir / "image_00" / "timestamps.txt"
    if stamps.is_file():
        meta["image_00_t_s"] = read_timestamps(stamps)[0].tolist()
    meta["content_hash"] = content_hash(  # identity of the content, not of its location
        [packets, t, cal.K, cal.R_cam_imu, cal.p_imu_cam_m], {"rectified_extrinsic": rectified})
    return Sequence(
        name=drive_dir.name, imu=imu, frame_t_s=t,
        truth=GroundTruth(p_world_imu_m=p, R_world_imu=R, v_world_imu_mps=v),
        reference_calibration=cal, image_size_px=size,
        image_paths=tuple(str(x) for x in images) or None, meta=meta,
    )


def _matrix_line(key: str, values: np.ndarray) -> str:
    return f"{key}: " + " ".join(f"{x:.17g}" for x in np.ravel(values)) + "\n"


def write_kitti_raw(
    sequence: Sequence, out_dir: str | Path, date: str = "2011_09_26", drive: int = 1,
    origin_lat_lon_alt: tuple[float, float, float] = (49.0, 8.4, 110.0),
) -> Path:
    """Write ``sequence`` in the KITTI raw layout under ``out_dir/<date>/``; returns the drive dir.

    One OXTS packet per frame: the truth state (world taken as ENU, origin put at
    ``origin_lat_lon_alt``) and the IMU linearly interpolated to the frame times (so a 100 Hz
    simulated IMU comes back as 10 Hz, as in real synced data). Timestamps are the frame times
    as seconds after midnight of ``date``. The calib files hold the *reference* calibration
    (what a user of the files starts from): imu_to_velo = identity, velo_to_cam = T_cam_imu,
    R_rect_00 = identity, P_rect_00 from the intrinsics. Images are copied when present.
    Written to a temporary folder first and renamed, so a failure leaves nothing half-written.
    """
    t = sequence.frame_t_s
    if t[0] < 0 or t[-1] >= 86400.0:
        raise KittiRawError(f"sequence {sequence.name!r}: frame times must lie within one day, got "
                            f"[{t[0]}, {t[-1]}] s")
    def interp(y):
        return np.stack([np.interp(t, sequence.imu.t_s, y[:, j]) for j in range(3)], 1)
    gt = sequence.truth
    packets = packets_from_states(gt.p_world_imu_m, gt.R_world_imu, gt.v_world_imu_mps,
                                  interp(sequence.imu.accel_imu_mps2),
                                  interp(sequence.imu.gyro_imu_radps), origin_lat_lon_alt)
    date_dir = Path(out_dir) / date
    drive_name = f"{date}_drive_{drive:04d}_sync"
    tmp = Path(out_dir) / f".{date}.{drive_name}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    drive_dir = tmp / drive_name
    (drive_dir / "oxts" / "data").mkdir(parents=True)
    for i, row in enumerate(packets):
        (drive_dir / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(f"{x:.17g}" for x in row) + "\n")
    midnight = np.datetime64(date.replace("_", "-"), "D")
    lines = "\n".join(format_timestamps(t, midnight)) + "\n"
    (drive_dir / "oxts" / "timestamps.txt").write_text(lines)
    (drive_dir / "image_00").mkdir()
    (drive_dir / "image_00" / "timestamps.txt").write_text(lines)
    if sequence.image_paths:
        (drive_dir / "image_00" / "data").mkdir()
        for i, src in enumerate(sequence.image_paths):
            shutil.copyfile(src, drive_dir / "image_00" / "data" / f"{i:010d}.png")
    _write_calib(tmp, sequence.reference_calibration, sequence.image_size_px)
    date_dir.mkdir(parents=True, exist_ok=True)
    for item in tmp.iterdir():
        target = date_dir / item.name
        if target.is_dir():
            shutil.rmtree(target)
        item.replace(target)
    tmp.rmdir()
    return date_dir / drive_name


def _write_calib(folder: Path, cal: Calibration, image_size_px: tuple[int, int]) -> None:
    R = cal.R_cam_imu[0]
    # Solve rather than -R p: published R are orthonormal to ~1e-7 only, and the loader
    # computes p = -R^T t, so this makes the round trip exact.
    t = np.linalg.solve(R.T, -cal.p_imu_cam_m[0])
    (folder / "calib_imu_to_velo.txt").write_text(
        "calib_time: simulated\n" + _matrix_line("R", np.eye(3)) + _matrix_line("T", np.zeros(3)))
    (folder / "calib_velo_to_cam.txt").write_text(
        "calib_time: simulated\n" + _matrix_line("R", R) + _matrix_line("T", t))
    P = np.zeros((3, 4))
    P[:, :3] = cal.K[0]
    (folder / "calib_cam_to_cam.txt").write_text(
        "calib_time: simulated\n" + _matrix_line("S_rect_00", np.array(image_size_px, float))
        + _matrix_line("R_rect_00", np.eye(3)) + _matrix_line("P_rect_00", P))


__all__ = ["KittiRawError", "OxtsError", "read_calib_file", "cam0_imu_transform",
           "reference_calibration", "load_kitti_raw", "write_kitti_raw"]
