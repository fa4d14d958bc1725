"""Smooth, car-like ground-truth trajectories with analytic velocity, acceleration and body rates.

A trajectory is a geometric path ``P(s)`` (a quintic B-spline in arc length s, metres) driven
along by a time law ``s(t)`` whose speed ``v(t) = s'(t)`` is a quintic B-spline with
non-negative coefficients (so the car never reverses, and a run of zero coefficients is an
exact stop). Everything the IMU needs follows by the chain rule, so the IMU can be synthesised
exactly:

    p = P(s),  v = P'(s) s',  a = P''(s) s'^2 + P'(s) s''.

Attitude is car-like (KITTI OXTS body axes: x forward, y left, z up): x along the path tangent,
``R_world_imu = Rz(psi) Ry(theta) Rx(phi)`` with heading ``psi`` and pitch ``theta`` of the
tangent and a road bank (roll) ``phi(s)``; the body rate is the ZYX Euler-rate map

    w = [phi' - psi' sin(theta),
         theta' cos(phi) + psi' sin(phi) cos(theta),
         -theta' sin(phi) + psi' cos(phi) cos(theta)].

Kinds: "straight" (constant speed and heading: a negative control for observability), "city"
(flat, 60-100 degree corners, a stop), "city_hills" (city plus grades and road bank),
"full3d" (stronger grades and bank, slalom, speed changes: excites every axis).
World frame: z up, origin and heading (+x) at the pose of t = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from avio.errors import AvioError
from avio.sequence import GroundTruth

if TYPE_CHECKING:
    from scipy.interpolate import BSpline

KINDS = ("straight", "city", "city_hills", "full3d")
_PATH_STEP_M = 0.5
_SPEED_KNOT_S = 1.0


class TrajectoryError(AvioError):
    """Bad trajectory request (unknown kind, non-positive duration, times outside the domain)."""


@dataclass(frozen=True)
class TrajectoryState:
    """The truth at m times (world z up; IMU body axes x forward, y left, z up).

    t_s: (m,) seconds. p_world_imu_m: (m, 3) metres. R_world_imu: (m, 3, 3).
    v_world_imu_mps: (m, 3) m/s. a_world_mps2: (m, 3) acceleration in the world frame, m/s^2
    (without gravity). omega_imu_radps: (m, 3) angular rate of the IMU frame in the IMU frame.
    """

    t_s: np.ndarray
    p_world_imu_m: np.ndarray
    R_world_imu: np.ndarray
    v_world_imu_mps: np.ndarray
    a_world_mps2: np.ndarray
    omega_imu_radps: np.ndarray


@dataclass(frozen=True)
class _Sines:
    """sum_i amp_i sin(2 pi s / wavelength_i + phase_i) and its s-derivative (units of amp per metre)."""

    amp: np.ndarray
    wavelength_m: np.ndarray
    phase: np.ndarray

    def __call__(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = 2 * np.pi / self.wavelength_m
        arg = s[..., None] * w + self.phase
        return (self.amp * np.sin(arg)).sum(-1), (self.amp * w * np.cos(arg)).sum(-1)

    @classmethod
    def none(cls) -> "_Sines":
        return cls(np.zeros(0), np.ones(0), np.zeros(0))

    @classmethod
    def random(cls, rng, n: int, peak: float, wavelength_m: tuple[float, float]) -> "_Sines":
        amp = rng.uniform(0.5, 1.0, n)
        amp *= peak / amp.sum()
        return cls(amp, rng.uniform(*wavelength_m, n), rng.uniform(0, 2 * np.pi, n))


class TrajectoryFn:
    """A car-like trajectory evaluated exactly at any times in ``[t_start_s, t_end_s]``.

    Call it with times (m,) seconds to get a TrajectoryState. ``kind``, ``duration_s`` and the
    design parameters are kept for provenance.
    """

    def __init__(self, kind: str, duration_s: float, path: BSpline, speed: BSpline, roll: _Sines, pad_s: float):
        self.kind = kind
        self.duration_s = float(duration_s)
        self.t_start_s = -float(pad_s)
        self.t_end_s = float(duration_s) + float(pad_s)
        self._path = path
        self._path_d1 = path.derivative(1)
        self._path_d2 = path.derivative(2)
        self._speed = speed
        self._speed_d1 = speed.derivative(1)
        self._dist = speed.antiderivative(1)
        self._dist0 = float(self._dist(0.0))
        self._roll = roll

    def distance_m(self, t_s: np.ndarray) -> np.ndarray:
        """(m,) arc length travelled since t = 0 (negative before), metres."""
        return self._dist(np.asarray(t_s, float)) - self._dist0

    def __call__(self, t_s: np.ndarray) -> TrajectoryState:
        from scipy.spatial.transform import Rotation  # scipy on a cache miss only (avio.sim.cache)

        t = np.atleast_1d(np.asarray(t_s, float))
        if t.size and (t.min() < self.t_start_s - 1e-9 or t.max() > self.t_end_s + 1e-9):
            raise TrajectoryError(
                f"avio.trajectory: times [{t.min():.3f}, {t.max():.3f}] s outside the trajectory "
                f"domain [{self.t_start_s:.3f}, {self.t_end_s:.3f}] s"
            )
        s = self.distance_m(t)
        sd, sdd = self._speed(t), self._speed_d1(t)
        d1, d2 = self._path_d1(s), self._path_d2(s)
        p = self._path(s)
        v = d1 * sd[:, None]
        a = d2 * (sd**2)[:, None] + d1 * sdd[:, None]

        h2 = d1[:, 0] ** 2 + d1[:, 1] ** 2
        h = np.sqrt(h2)
        psi = np.arctan2(d1[:, 1], d1[:, 0])
        theta = -np.arctan2(d1[:, 2], h)
        psi_s = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / h2
        h_s = (d1[:, 0] * d2[:, 0] + d1[:, 1] * d2[:, 1]) / h
        theta_s = -(h * d2[:, 2] - d1[:, 2] * h_s) / (h2 + d1[:, 2] ** 2)
        phi, phi_s = self._roll(s)
        psid, thetad, phid = psi_s * sd, theta_s * sd, phi_s * sd
        sth, cth, sph, cph = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
        omega = np.stack(
            [phid - psid * sth, thetad * cph + psid * sph * cth, -thetad * sph + psid * cph * cth], axis=1
        )
        R = Rotation.from_euler("ZYX", np.stack([psi, theta, phi], axis=1)).as_matrix()
        return TrajectoryState(t, p, R, v, a, omega)

    def ground_truth(self, t_s: np.ndarray) -> GroundTruth:
        """GroundTruth (poses and velocities) at times (m,) seconds."""
        st = self(t_s)
        return GroundTruth(st.p_world_imu_m, st.R_world_imu, st.v_world_imu_mps)


def _smootherstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (x * (6 * x - 15) + 10)


def _city_curvature(s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n,) curvature 1/m: straights of 40-130 m and 60-100 degree corners of radius 15-35 m,
    entered and left over 6 m ramps (C2), alternating at random sides."""
    kappa = np.zeros_like(s)
    ramp = 6.0
    pos = rng.uniform(20.0, 60.0)
    while pos < s[-1]:
        radius = rng.uniform(15.0, 35.0)
        angle = np.radians(rng.uniform(60.0, 100.0)) * rng.choice([-1.0, 1.0])
        arc = radius * abs(angle)
        plateau = _smootherstep((s - pos) / ramp) * _smootherstep((pos + arc + ramp - s) / ramp)
        kappa += np.sign(angle) / radius * plateau
        pos += arc + ramp + rng.uniform(40.0, 130.0)
    return kappa


def _make_path(kind: str, s_min: float, s_max: float, rng: np.random.Generator) -> tuple[BSpline, _Sines]:
    """Quintic path spline P(s) (s in [s_min, s_max], P(0) = 0) and the road bank phi(s) (rad)."""
    from scipy.integrate import cumulative_trapezoid
    from scipy.interpolate import make_interp_spline

    n_neg = int(np.ceil(-s_min / _PATH_STEP_M)) + 3
    n_pos = int(np.ceil(s_max / _PATH_STEP_M)) + 3
    s = _PATH_STEP_M * np.arange(-n_neg, n_pos + 1)
    kappa = np.zeros_like(s)
    grade, roll = _Sines.none(), _Sines.none()
    if kind != "straight":
        kappa = _city_curvature(s, rng)
    if kind == "city_hills":
        grade = _Sines.random(rng, 3, np.radians(4.0), (120.0, 400.0))
        roll = _Sines.random(rng, 2, np.radians(2.5), (60.0, 200.0))
    elif kind == "full3d":
        grade = _Sines.random(rng, 3, np.radians(8.0), (60.0, 250.0))
        roll = _Sines.random(rng, 3, np.radians(7.0), (30.0, 120.0))
        slalom = _Sines.random(rng, 2, 0.02, (30.0, 70.0))
        kappa = kappa + slalom(s)[0]
    psi = cumulative_trapezoid(kappa, s, initial=0.0)
    gamma = grade(s)[0]
    tangent = np.stack([np.cos(gamma) * np.cos(psi), np.cos(gamma) * np.sin(psi), np.sin(gamma)], axis=1)
    points = cumulative_trapezoid(tangent, s, axis=0, initial=0.0)
    i0 = n_neg
    # Start the world at the pose of s = 0: origin there, heading +x.
    points = points - points[i0]
    c, sn = np.cos(-psi[i0]), np.sin(-psi[i0])
    points = points @ np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]).T
    return make_interp_spline(s, points, k=5), roll


def ar1(x: np.ndarray, phi: float) -> np.ndarray:
    """The AR(1) ``y[n] = sqrt(1 - phi^2) x[n] + phi y[n-1]``, ``y[-1] = 0``, of x (n,): the same bits as
    ``scipy.signal.lfilter([sqrt(1 - phi^2)], [1, -phi], x)``."""
    # Written out: importing scipy.signal (and the scipy.stats it pulls in) costs ~0.4 s per process.
    gain = np.sqrt(1.0 - phi * phi)
    y = np.empty(len(x))
    prev = 0.0
    for n, xn in enumerate(x):
        prev = gain * xn + phi * prev
        y[n] = prev
    return y


def _make_speed(kind: str, duration_s: float, speed_mps: float, pad_s: float, n_stops: int, rng) -> BSpline:
    """Quintic speed spline v(t) >= 0 on [-pad_s, duration_s + pad_s] with mean ``speed_mps``
    over [0, duration_s]; each stop is 7 zero coefficients (an exact stop of ~2 s)."""
    from scipy.interpolate import BSpline

    k = 5
    n_int = int(np.ceil((duration_s + 2 * pad_s) / _SPEED_KNOT_S))
    knots = -pad_s + _SPEED_KNOT_S * np.arange(-k, n_int + k + 1)
    n_coef = len(knots) - k - 1
    if kind == "straight":
        coef = np.ones(n_coef)
    else:
        level = 0.25 if kind == "full3d" else 0.12
        # Slowly varying cruise speed: a unit-variance AR(1) over the knots, starting at 0.
        ar = ar1(np.r_[0.0, rng.standard_normal(n_coef - 1)], 0.9)
        coef = np.clip(1.0 + level * ar, 0.5, 1.6)
        t_coef = knots[: n_coef] + 0.5 * (k + 1) * _SPEED_KNOT_S  # Greville-like abscissae
        shape = np.array([0.7, 0.35, 0.08] + [0.0] * 7 + [0.08, 0.35, 0.7])
        for j in range(n_stops):
            centre = rng.uniform(0.25 + 0.5 * j / max(n_stops, 1), 0.25 + 0.5 * (j + 1) / max(n_stops, 1))
            i = int(np.searchsorted(t_coef, centre * duration_s)) - len(shape) // 2
            if i < 0 or i + len(shape) > n_coef:
                raise TrajectoryError(
                    f"avio.trajectory: a {duration_s} s drive is too short for {n_stops} stop(s)"
                )
            coef[i : i + len(shape)] *= shape
    spline = BSpline(knots, coef, k)
    dist = spline.antiderivative(1)
    return BSpline(knots, coef * speed_mps * duration_s / (dist(duration_s) - dist(0.0)), k)


def make_trajectory(
    kind: str,
    duration_s: float,
    speed_mps: float,
    seed: int,
    *,
    n_stops: int | None = None,
    pad_s: float = 2.0,
) -> TrajectoryFn:
    """A car-like trajectory of ``kind`` lasting ``duration_s`` at mean speed ``speed_mps``.

    The distance driven over [0, duration_s] is exactly ``speed_mps * duration_s`` (along the
    path). It is defined on [-pad_s, duration_s + pad_s] so that camera times shifted by a
    time offset stay inside. n_stops: exact stops of ~2 s (default 1 for city kinds of
    20 s or more, 0 otherwise).
    A pure function of its arguments.
    """
    if kind not in KINDS:
        raise TrajectoryError(f"avio.trajectory: unknown kind {kind!r}; choose one of {KINDS}")
    if not duration_s > 0 or not speed_mps > 0 or pad_s < 0:
        raise TrajectoryError(
            f"avio.trajectory: need duration_s > 0, speed_mps > 0, pad_s >= 0; got {duration_s}, {speed_mps}, {pad_s}"
        )
    if n_stops is None:
        n_stops = 1 if kind in ("city", "city_hills") and duration_s >= 20.0 else 0
    rng = np.random.default_rng(seed)
    speed = _make_speed(kind, duration_s, speed_mps, pad_s, n_stops, rng)
    dist = speed.antiderivative(1)
    s0 = float(dist(0.0))
    s_min, s_max = float(dist(-pad_s)) - s0 - 5.0, float(dist(duration_s + pad_s)) - s0 + 5.0
    path, roll = _make_path(kind, s_min, s_max, rng)
    return TrajectoryFn(kind, duration_s, path, speed, roll, pad_s)
