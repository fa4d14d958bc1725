"""KITTI raw OXTS packets: parsing, the devkit's Mercator pose conversion, and its inverse.

One packet = one text line of 30 numbers (``oxts/dataformat.txt``): lat, lon (deg), alt (m),
roll, pitch, yaw (rad; yaw 0 = east, counter-clockwise), vn, ve, vf, vl, vu (m/s), ax, ay, az
(body-frame specific force, gravity included: az ≈ +9.8 when level), af, al, au (same in the
level forward/left/up frame), wx, wy, wz (body-frame rates, rad/s), wf, wl, wu (level-frame
rates), pos_accuracy, vel_accuracy, navstat, numsats, posmode, velmode, orimode.

Checked on the real 2011_09_26 packets: (af, al, au) and (wf, wl, wu) are (ax, ay, az) and
(wx, wy, wz) rotated by roll and pitch into the heading frame (to 0.02 m/s^2 and 7e-5 rad/s),
but ``vl`` has the *opposite* sign of the leftward component of (ve, vn) in that frame (the
course from the positions is ~0.5 deg left of the yaw; vl says right). The loaders use ve, vn,
vu only; the writer follows dataformat.txt (vl leftward).

Body axes: x forward, y left, z up; ``R_enu_imu = Rz(yaw) Ry(pitch) Rx(roll)`` (devkit
``convertOxtsToPose``). Positions: the devkit's Mercator projection with the scale
``cos(lat0)`` of the first packet, which is metric (to ~1e-5 over a few km) near ``lat0``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from avio.datasets._io import read_numeric_table
from avio.datasets.kitti00 import KittiDataError

EARTH_RADIUS_M = 6378137.0
OXTS_FIELDS = (
    "lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu",
    "ax", "ay", "az", "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu",
    "pos_accuracy", "vel_accuracy", "navstat", "numsats", "posmode", "velmode", "orimode",
)
F = {name: i for i, name in enumerate(OXTS_FIELDS)}


class OxtsError(KittiDataError):
    """An OXTS packet file or timestamp file is missing or malformed (file and line named)."""


def read_oxts_packets(data_dir: str | Path) -> np.ndarray:
    """(n, 30) packets from ``oxts/data/*.txt`` sorted by name; OxtsError naming the file."""
    files = sorted(Path(data_dir).glob("*.txt"))
    if not files:
        raise OxtsError(f"{data_dir}: no OXTS packet files (*.txt)")
    rows = [read_numeric_table(f, len(OXTS_FIELDS), error=OxtsError) for f in files]
    for f, r in zip(files, rows):
        if len(r) != 1:
            raise OxtsError(f"{f}: expected one packet line, got {len(r)}")
    return np.concatenate(rows)


def read_timestamps(path: str | Path) -> tuple[np.ndarray, np.datetime64]:
    """``(t_s (n,), midnight)``: KITTI ``YYYY-MM-DD HH:MM:SS.fffffffff`` lines as seconds since
    the midnight of the first line (ns resolution kept); strictly increasing, else OxtsError."""
    path = Path(path)
    if not path.is_file():
        raise OxtsError(f"{path}: file not found")
    stamps = []
    with open(path) as handle:
        for line_no, line in enumerate(handle, start=1):
            if not line.strip():
                continue
            try:
                stamps.append(np.datetime64(line.strip().replace(" ", "T"), "ns"))
            except ValueError:
                raise OxtsError(f"{path}:{line_no}: not a timestamp: {line.strip()[:60]!r}") from None
    if not stamps:
        raise OxtsError(f"{path}: no timestamps")
    stamps = np.array(stamps)
    midnight = stamps[0].astype("datetime64[D]")
    t = (stamps - midnight).astype(np.int64) * 1e-9
    bad = np.flatnonzero(np.diff(stamps).astype(np.int64) <= 0)
    if bad.size:
        raise OxtsError(f"{path}:{bad[0] + 2}: timestamp does not increase")
    return t, midnight


def format_timestamps(t_s: np.ndarray, midnight: np.datetime64) -> list[str]:
    """Inverse of ``read_timestamps``: KITTI timestamp lines (ns resolution)."""
    stamps = midnight.astype("datetime64[ns]") + np.round(np.asarray(t_s) * 1e9).astype(np.int64)
    return [str(s).replace("T", " ") for s in stamps]


def mercator_scale(lat0_deg: float) -> float:
    """Devkit ``latToScale``: cos of the reference latitude."""
    return float(np.cos(np.radians(lat0_deg)))


def latlon_to_mercator(lat_deg, lon_deg, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Devkit ``latlonToMercator``: (mx, my) metres, x east, y north."""
    mx = scale * np.radians(lon_deg) * EARTH_RADIUS_M
    my = scale * EARTH_RADIUS_M * np.log(np.tan(np.radians(90.0 + np.asarray(lat_deg)) / 2.0))
    return mx, my


def mercator_to_latlon(mx, my, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of ``latlon_to_mercator``, degrees."""
    lon = np.degrees(np.asarray(mx) / (scale * EARTH_RADIUS_M))
    lat = 2.0 * np.degrees(np.arctan(np.exp(np.asarray(my) / (scale * EARTH_RADIUS_M)))) - 90.0
    return lat, lon


def oxts_enu_states(packets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(p_world_imu_m (n,3), R_world_imu (n,3,3), v_world_imu_mps (n,3))`` in a gravity-aligned
    world: x east, y north (Mercator), z up, origin at the first packet's position."""
    scale = mercator_scale(packets[0, F["lat"]])
    mx, my = latlon_to_mercator(packets[:, F["lat"]], packets[:, F["lon"]], scale)
    p = np.stack([mx, my, packets[:, F["alt"]]], axis=1)
    R = Rotation.from_euler(
        "ZYX", packets[:, [F["yaw"], F["pitch"], F["roll"]]]
    ).as_matrix()
    v = packets[:, [F["ve"], F["vn"], F["vu"]]]
    return p - p[0], R, v


def oxts_to_poses(packets: np.ndarray) -> np.ndarray:
    """(n, 4, 4) devkit ``convertOxtsToPose``: IMU poses relative to the first one
    (``inv(T_0) · T_k``; that frame is *not* gravity-aligned when the car starts tilted)."""
    scale = mercator_scale(packets[0, F["lat"]])
    mx, my = latlon_to_mercator(packets[:, F["lat"]], packets[:, F["lon"]], scale)
    T = np.tile(np.eye(4), (len(packets), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("ZYX", packets[:, [F["yaw"], F["pitch"], F["roll"]]]).as_matrix()
    T[:, :3, 3] = np.stack([mx, my, packets[:, F["alt"]]], axis=1)
    return np.linalg.inv(T[0]) @ T


def packets_from_states(
    p_world_imu_m: np.ndarray, R_world_imu: np.ndarray, v_world_imu_mps: np.ndarray,
    accel_imu_mps2: np.ndarray, gyro_imu_radps: np.ndarray,
    origin_lat_lon_alt: tuple[float, float, float] = (49.0, 8.4, 110.0),
) -> np.ndarray:
    """(n, 30) packets for IMU states in an ENU world (x east, y north, z up, metres).

    The world origin is put at ``origin_lat_lon_alt`` (deg, deg, m); Mercator scale from its
    latitude, so ``oxts_enu_states`` of the result gives back ``p - p[0]``, R and v. Level-frame
    fields (vf, vl, af, al, au, wf, wl, wu) rotate the world/body vectors by the heading only.
    Accuracy/status fields are written as a good RTK fix (0.01 m, 0.01 m/s, navstat 4, 10 sats,
    modes 6).
    """
    n = len(p_world_imu_m)
    lat0, lon0, alt0 = origin_lat_lon_alt
    scale = mercator_scale(lat0)
    mx0, my0 = latlon_to_mercator(lat0, lon0, scale)
    p = p_world_imu_m - p_world_imu_m[0]
    lat, lon = mercator_to_latlon(mx0 + p[:, 0], my0 + p[:, 1], scale)
    yaw_pitch_roll = Rotation.from_matrix(R_world_imu).as_euler("ZYX")
    R_level = Rotation.from_euler("Z", yaw_pitch_roll[:, :1]).as_matrix()
    # level-frame vectors: R_level^T (world vector); body vectors go to the world first.
    def level(w):
        return np.einsum("nji,nj->ni", R_level, w)
    def to_world(b):
        return np.einsum("nij,nj->ni", R_world_imu, b)
    out = np.zeros((n, len(OXTS_FIELDS)))
    out[:, F["lat"]], out[:, F["lon"]], out[:, F["alt"]] = lat, lon, alt0 + p[:, 2]
    out[:, [F["yaw"], F["pitch"], F["roll"]]] = yaw_pitch_roll
    out[:, [F["ve"], F["vn"], F["vu"]]] = v_world_imu_mps
    out[:, [F["vf"], F["vl"]]] = level(v_world_imu_mps)[:, :2]
    out[:, [F["ax"], F["ay"], F["az"]]] = accel_imu_mps2
    out[:, [F["af"], F["al"], F["au"]]] = level(to_world(accel_imu_mps2))
    out[:, [F["wx"], F["wy"], F["wz"]]] = gyro_imu_radps
    out[:, [F["wf"], F["wl"], F["wu"]]] = level(to_world(gyro_imu_radps))
    out[:, F["pos_accuracy"]:] = [0.01, 0.01, 4, 10, 6, 6, 6]
    return out
