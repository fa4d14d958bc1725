"""Everything specific to the paper (Arbabmir & Ebrahimi 2019) that the report sets beside ours.

The paper's Tables 2–3 were measured on real KITTI drives of ~540 m and ~928 m (real camera,
real IMU, GPS/INS ground truth). Our problems reproduce those drives in part: ``synthetic``
simulates a drive of the same length and speed (simulated IMU and camera), ``kitti00`` replays
KITTI 00 frames 15–796 / 2404–3553 with the real IMU and ground truth and a simulated camera,
``kitti00_tracks`` is all real but a different window. The paper's values are shown only beside
our drives that stand for the paper's (``paper_drive``), labelled with what is real and what
is simulated (``data_label``).
"""

from __future__ import annotations

from avio.reference import PAPER_TABLE1, PAPER_TABLE23  # the values live beside the paper's reference calibration

PAPER_DATA = "paper: real KITTI drive (real camera and IMU, GPS/INS truth)"

# Our stand-ins for the paper's drives, by name (simulator presets and kitti00 windows of the
# same length and speed; "clean_928m" is kitti00's 929 m window without ground-truth defects),
# and kitti00's frame windows.
_PAPER_DRIVES = {"paper_540m": "540m", "paper_928m": "928m", "clean_928m": "928m"}
_KITTI00_WINDOWS = {(15, 796): "540m", (2404, 3553): "928m", (3000, 4077): "928m"}
_DATA = {
    "synthetic": "ours: simulated drive (simulated IMU, camera and truth)",
    "kitti00": "ours: KITTI 00 real IMU and ground truth, simulated camera",
    "kitti00_tracks": "ours: all real (KITTI 00 IMU, ground truth and feature tracks)",
    "kitti_raw": "ours: all real (KITTI raw drive, OXTS truth, KLT tracks)",
    "euroc": "ours: all real (EuRoC MAV, Vicon truth; errors against Kalibr)",
}
# Problems whose camera is the KITTI 2011_10_03 one of the paper's Table 1
_KITTI_CAMERA = ("synthetic", "kitti00", "kitti00_tracks", "kitti_raw")


def table1_applies(problem_name: str) -> bool:
    """Whether the paper's Table 1 (KITTI's camera: its bounds, reference and PSO-GA result)
    belongs beside this problem's calibrations."""
    return problem_name in _KITTI_CAMERA


def paper_drive(problem_config: dict, which: str) -> str | None:
    """``"540m"`` / ``"928m"`` when the ``which`` ("calibration" or "holdout") drive of the
    problem (``record["config"]["problem"]``) stands for one of the paper's, else None."""
    name = problem_config.get("name")
    params = problem_config.get("params") or {}
    if name not in ("synthetic", "kitti00"):
        return None
    if which == "calibration":  # the first calibration drive (``drives``; older configs: drive/window)
        drives = params.get("drives") or [params.get("drive") or params.get("window") or "paper_540m"]
        key = drives[0] if isinstance(drives, (list, tuple)) and drives and not isinstance(drives[0], (int, float)) \
            else drives
    else:
        key = params.get("holdout", "paper_928m" if name == "synthetic" else "clean_928m")
    if isinstance(key, str):
        return _PAPER_DRIVES.get(key)
    if name == "kitti00" and isinstance(key, (list, tuple)) and len(key) == 2:
        return _KITTI00_WINDOWS.get((int(key[0]), int(key[1])))
    return None


def data_label(problem_name: str) -> str:
    """What is real and what is simulated in our problem's data, in words."""
    return _DATA.get(problem_name, f"ours: problem {problem_name}")

__all__ = ["PAPER_DATA", "PAPER_TABLE1", "PAPER_TABLE23", "data_label", "paper_drive", "table1_applies"]
