"""The KITTI 2011_10_03 calibration (the paper's reference) and the values the paper reports (Tables 1-3).

The matrices are the published KITTI raw calibration of 2011_10_03 (calib_imu_to_velo,
calib_velo_to_cam, calib_cam_to_cam); ../shared/data/README.md lists them.
"""

from __future__ import annotations

import numpy as np

from avio.calibration import Calibration

R_VELO_IMU = np.array(
    [
        [9.999976e-01, 7.553071e-04, -2.035826e-03],
        [-7.854027e-04, 9.998898e-01, -1.482298e-02],
        [2.024406e-03, 1.482454e-02, 9.998881e-01],
    ]
)
T_VELO_IMU_M = np.array([-8.086759e-01, 3.195559e-01, -7.997231e-01])
R_CAM_VELO = np.array(
    [
        [7.967514e-03, -9.999679e-01, -8.462264e-04],
        [-2.771053e-03, 8.241710e-04, -9.999958e-01],
        [9.999644e-01, 7.969825e-03, -2.764397e-03],
    ]
)
T_CAM_VELO_M = np.array([-1.377769e-02, -5.542117e-02, -2.918589e-01])
R_RECT_00 = np.array(
    [
        [9.999454e-01, 7.259129e-03, -7.519551e-03],
        [-7.292213e-03, 9.999638e-01, -4.381729e-03],
        [7.487471e-03, 4.436324e-03, 9.999621e-01],
    ]
)
FX_PX, FY_PX, CX_PX, CY_PX = 718.856, 718.856, 607.1928, 185.2157
IMAGE_SIZE_PX = (1241, 376)


def T_cam_imu_2011_10_03(rectified: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(R_cam_imu, t_cam_imu_m)`` of cam0, unrectified or rectified (``R_rect_00`` applied)."""
    R = R_CAM_VELO @ R_VELO_IMU
    t = R_CAM_VELO @ T_VELO_IMU_M + T_CAM_VELO_M
    if rectified:
        R, t = R_RECT_00 @ R, R_RECT_00 @ t
    return R, t


def kitti_2011_10_03_calibration(rectified: bool = False) -> Calibration:
    """The paper's reference calibration: rectified P_rect_00 intrinsics with the
    unrectified (default) or rectified IMU→cam0 extrinsics; batch of 1."""
    R_cam_imu, t_cam_imu = T_cam_imu_2011_10_03(rectified)
    p_imu_cam = -R_cam_imu.T @ t_cam_imu
    return Calibration.single(FX_PX, FY_PX, CX_PX, CY_PX, R_cam_imu, p_imu_cam)


# The paper's Table 1: variable -> (reference, lower, upper, PSO–GA result).
PAPER_TABLE1 = {
    "fx": (718.8560, 700.0, 740.0, 717.4954),
    "fy": (718.8560, 700.0, 740.0, 720.5287),
    "cx": (607.1928, 600.0, 620.0, 602.0016),
    "cy": (185.2157, 170.0, 200.0, 180.1210),
    "roll": (119.5262, 110.0, 140.0, 132.3246),
    "pitch": (-89.4279, -100.0, -80.0, -89.5779),
    "yaw": (-28.722, -50.0, -20.0, -41.6586),
    "tx": (1.1022, 0.8, 1.3, 1.0169),
    "ty": (-0.3191, -0.5, -0.1, -0.2687),
    "tz": (0.7461, 0.5, 1.0, 0.7957),
}

# The paper's Tables 2-3: (drive, state) -> {method: (rmse, mean, std)}; metres, m/s, degrees.
PAPER_TABLE23 = {
    ("540m", "position"): {"VIO reference": (4.8944, 2.3549, 1.1641), "AVIO": (2.0736, 1.7936, 0.8551)},
    ("540m", "velocity"): {"VIO reference": (0.5281, 0.4598, 0.1705), "AVIO": (0.1513, 0.1472, 0.1368)},
    ("540m", "attitude"): {"VIO reference": (2.3558, 0.6493, 1.1323), "AVIO": (1.9108, 0.5101, 1.0023)},
    ("928m", "position"): {"VIO reference": (27.3307, 18.3963, 7.2341), "AVIO": (19.8791, 12.6847, 2.3142)},
    ("928m", "velocity"): {"VIO reference": (1.5723, 0.9824, 0.9876), "AVIO": (1.0134, 0.7925, 0.6541)},
    ("928m", "attitude"): {"VIO reference": (2.2124, 1.2344, 1.9856), "AVIO": (1.3482, 0.9821, 1.4422)},
}
