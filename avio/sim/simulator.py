"""The KITTI-like simulator: a drive whose truth (trajectory, IMU biases, calibration) is known.

``simulate(config, seed)`` is a pure function of its arguments. It builds a car-like trajectory
(avio.sim.trajectory), synthesises the 100 Hz IMU from it exactly (docs/model.md, Eq. 10):

    a_m = R_world_imu^T (a_world - g_world) + b_a + n_a,    w_m = w + b_g + n_g,

with white noise of standard deviation ``density / sqrt(dt)`` and biases that random-walk with
``walk * sqrt(dt)`` per sample, draws a truth calibration near the KITTI 2011_10_03 reference,
lines the road with landmarks and projects them through the truth camera into triplet tracks
(avio.sim.camera) or renders grayscale images (avio.sim.render).

Random streams: one ``numpy.random.SeedSequence(seed)`` is split into independent children for
the trajectory, the calibration error, the IMU, the landmarks, the tracks and the images, so
changing e.g. the pixel noise leaves the trajectory and the IMU unchanged.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from avio.calibration import Calibration
from avio.errors import AvioError
from avio.geometry import so3_exp
from avio.reference import IMAGE_SIZE_PX, kitti_2011_10_03_calibration
from avio.sequence import ImuNoise, ImuSamples, Sequence, content_hash
from avio.sim.trajectory import KINDS, TrajectoryFn, make_trajectory

GRAVITY_MPS2 = 9.81
# GTSAM's KITTI figures (../shared/data/kitti00/KittiEquivBiasedImu_metadata.txt) read as GTSAM
# reads them: continuous-time densities. At 100 Hz that is 0.1 m/s^2 and 1.75e-3 rad/s per
# sample, a few times the real drive's high-frequency scatter (~0.02-0.035 m/s^2, ~0.4-1.6e-3
# rad/s, from second differences of KittiEquivBiasedImu.txt). These are ImuNoise()'s defaults.
OXTS_IMU_NOISE = ImuNoise()
_STREAMS = ("trajectory", "calibration", "imu", "landmarks", "tracks", "render")
#: The streams a ``noise_seed`` replaces: IMU noise and bias realisations; pixel noise, outliers
#: and which landmarks the front end keeps. The trajectory, the world and the camera stay.
NOISE_STREAMS = ("imu", "tracks")


class SimulatorError(AvioError):
    """A SimConfig that cannot be simulated; the message names the field and the value."""


@dataclass(frozen=True)
class SimConfig:
    """Everything a simulated drive depends on, besides the seed.

    trajectory: one of avio.sim.trajectory.KINDS; duration_s, seconds; speed_mps: mean speed (the
        drive is ``speed_mps * duration_s`` metres); n_stops: exact stops (None: kind default).
    imu_rate_hz, camera_rate_hz: sample rates; frames and IMU both start at t = 0.
    imu_noise_on: white noise and bias random walks on/off; imu_noise: their densities (also
        handed to the filter as Sequence.imu_noise; default OXTS_IMU_NOISE).
    accel_bias_mps2, gyro_bias_radps: initial biases (x, y, z) in the IMU frame; None draws them
        from N(0, accel_bias_sigma_mps2 / gyro_bias_sigma_radps) when imu_noise_on, else zero.
    pixel_noise_px: Gaussian pixel noise; outlier_fraction: share of wrong matches per triplet;
        max_features: features per triplet (bucketing), None for all.
    pixel_noise_per_triplet: the pixel noise drawn afresh for every triplet instead of once per
        observation (avio.sim.camera.simulate_tracks: overlapping triplets then share no noise;
        a diagnostic of the filter's independence assumption, studies/objective/likelihood_tilt.py).
    time_offset_s: the truth camera's clock offset (frame stamped t exposed at IMU time t + offset).
    calibration_error: "realistic" (drawn from the seed: N(0, sizes[0]) px on fx, fy,
        N(0, sizes[1]) px on cx, cy, a rotation of sizes[2] degrees about a random axis and a
        translation of sizes[3] metres in a random direction, both in the IMU frame), "none"
        (truth == reference) or "explicit" (calibration_delta).
    calibration_error_sizes: (focal_px, principal_px, rotation_deg, translation_m).
    calibration_delta: explicit (dfx, dfy, dcx, dcy px, rotation vector x, y, z deg, dp x, y, z m);
        truth ``R_cam_imu = R_ref exp(rotvec)``, ``p_imu_cam = p_ref + dp``.
    landmarks_per_m: landmark density along the road.
    output: "tracks" (Sequence.tracks) or "images" (Sequence.image_paths; tracks None).
    image_size_px: (width, height).
    """

    trajectory: str = "city"
    duration_s: float = 78.0
    speed_mps: float = 540.0 / 78.0
    n_stops: int | None = None
    imu_rate_hz: float = 100.0
    camera_rate_hz: float = 10.0
    imu_noise_on: bool = True
    imu_noise: ImuNoise = OXTS_IMU_NOISE
    accel_bias_mps2: tuple[float, float, float] | None = None
    gyro_bias_radps: tuple[float, float, float] | None = None
    accel_bias_sigma_mps2: float = 0.01
    gyro_bias_sigma_radps: float = 5e-5
    pixel_noise_px: float = 0.7
    outlier_fraction: float = 0.05
    max_features: int | None = 30
    pixel_noise_per_triplet: bool = False
    time_offset_s: float = 0.0
    calibration_error: str = "realistic"
    calibration_error_sizes: tuple[float, float, float, float] = (1.5, 1.5, 0.4, 0.03)
    calibration_delta: tuple[float, ...] | None = None
    landmarks_per_m: float = 4.0
    output: str = "tracks"
    image_size_px: tuple[int, int] = IMAGE_SIZE_PX

    @classmethod
    def paper_540m(cls, **overrides) -> "SimConfig":
        """The paper's Table 2 drive: ~540 m in ~78 s (7 m/s), flat city."""
        return cls(**{"trajectory": "city", "duration_s": 78.0, "speed_mps": 540.0 / 78.0, **overrides})

    @classmethod
    def paper_928m(cls, **overrides) -> "SimConfig":
        """The paper's Table 3 drive: ~928 m in ~115 s (8 m/s), city with hills."""
        return cls(**{"trajectory": "city_hills", "duration_s": 115.0, "speed_mps": 928.0 / 115.0, **overrides})

    @classmethod
    def full3d_540m(cls, **overrides) -> "SimConfig":
        """An excited rig: ~540 m in ~78 s (7 m/s) on the ``full3d`` trajectory (grades of ~8 deg,
        road bank of ~7 deg, slalom, speed changes, no stop): rotation about every axis, so that
        all ten calibration variables are determined (issue 33; a flat city drive leaves the
        lever arm's dy, dz nearly free)."""
        return cls(**{"trajectory": "full3d", "duration_s": 78.0, "speed_mps": 540.0 / 78.0, **overrides})

    def validate(self) -> None:
        """Raise SimulatorError naming the first bad field."""
        checks = [
            ("trajectory", self.trajectory in KINDS, f"one of {KINDS}"),
            ("duration_s", self.duration_s > 0, "> 0"),
            ("speed_mps", self.speed_mps > 0, "> 0"),
            ("imu_rate_hz", self.imu_rate_hz > 0, "> 0"),
            ("camera_rate_hz", 0 < self.camera_rate_hz <= self.imu_rate_hz, "in (0, imu_rate_hz]"),
            ("pixel_noise_px", self.pixel_noise_px >= 0, ">= 0"),
            ("outlier_fraction", 0 <= self.outlier_fraction <= 1, "in [0, 1]"),
            ("max_features", self.max_features is None or self.max_features >= 1, "None or >= 1"),
            ("time_offset_s", abs(self.time_offset_s) <= 1.0, "within +-1 s"),
            ("calibration_error", self.calibration_error in ("realistic", "none", "explicit"),
             "'realistic', 'none' or 'explicit'"),
            ("calibration_delta", self.calibration_error != "explicit"
             or (self.calibration_delta is not None and len(self.calibration_delta) == 10), "10 numbers"),
            ("output", self.output in ("tracks", "images"), "'tracks' or 'images'"),
            ("landmarks_per_m", self.landmarks_per_m > 0, "> 0"),
        ]
        for name, ok, want in checks:
            if not ok:
                raise SimulatorError(f"SimConfig.{name} = {getattr(self, name)!r}: must be {want}")


@dataclass(frozen=True)
class SimWorld:
    """The hidden truth behind a simulated Sequence (for tests and diagnostics).

    trajectory: the exact TrajectoryFn. landmarks_world: (n_lm, 3) metres.
    accel_bias_mps2, gyro_bias_radps: (m, 3) true biases at the IMU samples.
    """

    trajectory: TrajectoryFn
    landmarks_world: np.ndarray
    accel_bias_mps2: np.ndarray
    gyro_bias_radps: np.ndarray


def truth_calibration(config: SimConfig, rng: np.random.Generator) -> Calibration:
    """The simulated camera's true calibration: the KITTI reference plus ``config``'s error."""
    ref = kitti_2011_10_03_calibration()
    if config.calibration_error == "none":
        delta = np.zeros(10)
    elif config.calibration_error == "explicit":
        delta = np.asarray(config.calibration_delta, float)
    else:
        focal, principal, rot_deg, trans_m = config.calibration_error_sizes
        axes = rng.standard_normal((2, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        delta = np.r_[rng.normal(0, focal, 2), rng.normal(0, principal, 2), rot_deg * axes[0], trans_m * axes[1]]
    return Calibration.single(
        ref.fx_px[0] + delta[0],
        ref.fy_px[0] + delta[1],
        ref.cx_px[0] + delta[2],
        ref.cy_px[0] + delta[3],
        ref.R_cam_imu[0] @ so3_exp(np.radians(delta[4:7])),
        ref.p_imu_cam_m[0] + delta[7:10],
        config.time_offset_s,
    )


def synthesize_imu(
    trajectory: TrajectoryFn,
    t_s: np.ndarray,
    gravity_world_mps2: np.ndarray,
    noise: ImuNoise | None,
    accel_bias0_mps2: np.ndarray,
    gyro_bias0_radps: np.ndarray,
    rng: np.random.Generator,
) -> tuple[ImuSamples, np.ndarray, np.ndarray]:
    """IMU samples at times t_s (m,) (uniform spacing dt) from the exact trajectory.

    Specific force ``R_world_imu^T (a_world - g_world) + b_a + n_a`` and rate ``w + b_g + n_g``;
    with ``noise`` None the biases stay at their initial values and there is no noise.
    Returns (ImuSamples, accel bias (m, 3), gyro bias (m, 3)).
    """
    st = trajectory(t_s)
    m = len(t_s)
    f = np.einsum("nji,nj->ni", st.R_world_imu, st.a_world_mps2 - gravity_world_mps2)
    b_a = np.broadcast_to(np.asarray(accel_bias0_mps2, float), (m, 3)).copy()
    b_g = np.broadcast_to(np.asarray(gyro_bias0_radps, float), (m, 3)).copy()
    accel, gyro = f + b_a, st.omega_imu_radps + b_g
    if noise is not None:
        dt = float(np.median(np.diff(t_s)))
        steps = rng.standard_normal((4, m, 3))
        steps[:2, 0] = 0.0  # biases start at their initial values
        b_a += np.cumsum(noise.accel_bias_walk * np.sqrt(dt) * steps[0], axis=0)
        b_g += np.cumsum(noise.gyro_bias_walk * np.sqrt(dt) * steps[1], axis=0)
        accel = f + b_a + noise.accel_noise / np.sqrt(dt) * steps[2]
        gyro = st.omega_imu_radps + b_g + noise.gyro_noise / np.sqrt(dt) * steps[3]
    return ImuSamples(np.asarray(t_s, float), accel, gyro), b_a, b_g


def _initial_bias(value, sigma: float, on: bool, rng: np.random.Generator) -> np.ndarray:
    draw = rng.normal(0.0, sigma, 3)  # always drawn, so the stream does not depend on the option
    if value is not None:
        return np.asarray(value, float)
    return draw if on else np.zeros(3)


def _plain_seed(seed: int | tuple[int, ...]) -> int | list[int]:
    """The seed as JSON-ready ints (for the meta, the name and the content hash)."""
    return int(seed) if np.ndim(seed) == 0 else [int(v) for v in seed]


def simulate_world(config: SimConfig, seed: int | tuple[int, ...], image_dir: str | Path | None = None,
                   true_calibration: Calibration | None = None,
                   noise_seed: int | tuple[int, ...] | None = None) -> tuple[Sequence, SimWorld]:
    """``simulate`` plus the hidden truth (SimWorld) behind the sequence."""
    from avio.sim.camera import make_landmarks, simulate_tracks  # scipy's splines: not for a cached drive

    config.validate()
    streams = _seed_streams(seed, noise_seed)
    rngs = {k: np.random.default_rng(v) for k, v in streams.items()}
    trajectory = make_trajectory(
        config.trajectory, config.duration_s, config.speed_mps,
        int(streams["trajectory"].generate_state(1)[0]), n_stops=config.n_stops,
    )
    gravity = np.array([0.0, 0.0, -GRAVITY_MPS2])
    t_imu = np.arange(int(np.floor(config.duration_s * config.imu_rate_hz + 1e-9)) + 1) / config.imu_rate_hz
    frame_t = np.arange(int(np.floor(config.duration_s * config.camera_rate_hz + 1e-9)) + 1) / config.camera_rate_hz
    b_a0 = _initial_bias(config.accel_bias_mps2, config.accel_bias_sigma_mps2, config.imu_noise_on, rngs["imu"])
    b_g0 = _initial_bias(config.gyro_bias_radps, config.gyro_bias_sigma_radps, config.imu_noise_on, rngs["imu"])
    imu, b_a, b_g = synthesize_imu(
        trajectory, t_imu, gravity, config.imu_noise if config.imu_noise_on else None, b_a0, b_g0, rngs["imu"]
    )
    truth = trajectory.ground_truth(frame_t)
    reference = kitti_2011_10_03_calibration()
    drawn = truth_calibration(config, rngs["calibration"])
    true_cal = drawn if true_calibration is None else true_calibration
    landmarks = make_landmarks(truth, rngs["landmarks"], points_per_m=config.landmarks_per_m)

    cal_arrays = [getattr(c, k) for c in (reference, true_cal) for k in Calibration.__dataclass_fields__]
    arrays = [imu.t_s, imu.accel_imu_mps2, imu.gyro_imu_radps, frame_t, truth.p_world_imu_m,
              truth.R_world_imu, truth.v_world_imu_mps, landmarks, *cal_arrays]
    tracks, image_paths = None, None
    if config.output == "tracks":
        tracks = simulate_tracks(
            trajectory, frame_t, true_cal, landmarks, config.image_size_px, config.pixel_noise_px,
            config.outlier_fraction, config.max_features, rngs["tracks"],
            noise_per_triplet=config.pixel_noise_per_triplet,
        )
        arrays += [tracks.frame_index, tracks.uv_px, tracks.valid]
    seed_value = _plain_seed(seed)
    noise_value = None if noise_seed is None else _plain_seed(noise_seed)
    config_dict, extra = _hash_extra(config, seed_value, noise_value)
    data_hash = content_hash(arrays, extra)
    if config.output == "images":
        from avio.sim.render import render_frames  # OpenCV only when rendering

        if image_dir is None:
            raise SimulatorError("SimConfig.output = 'images' needs an image_dir to render into")

        image_paths = render_frames(
            trajectory, frame_t, true_cal, landmarks, config.image_size_px,
            Path(image_dir) / f"sim_{data_hash[:16]}", rngs["render"],
        )
    sequence = Sequence(
        name=f"sim_{config.trajectory}_{'_'.join(map(str, np.atleast_1d(seed_value)))}"
             + ("" if noise_value is None else f"_noise_{'_'.join(map(str, np.atleast_1d(noise_value)))}"),
        imu=imu,
        frame_t_s=frame_t,
        truth=truth,
        reference_calibration=reference,
        image_size_px=tuple(config.image_size_px),
        tracks=tracks,
        image_paths=image_paths,
        truth_calibration=true_cal,
        gravity_world_mps2=gravity,
        imu_noise=config.imu_noise,
        meta={
            "source": "avio.simulator",
            "config": config_dict,
            "seed": seed_value,
            **({} if noise_value is None else {"noise_seed": noise_value}),
            "truth_calibration_given": true_calibration is not None,
            "content_hash": data_hash,
            "true_accel_bias0_mps2": b_a0.tolist(),
            "true_gyro_bias0_radps": b_g0.tolist(),
            "n_landmarks": int(len(landmarks)),
        },
    )
    return sequence, SimWorld(trajectory, landmarks, b_a, b_g)


def _seed_streams(seed, noise_seed) -> dict[str, np.random.SeedSequence]:
    """One seed sequence per random stream; with ``noise_seed`` the measurement-noise streams from it."""
    streams = dict(zip(_STREAMS, np.random.SeedSequence(seed).spawn(len(_STREAMS))))
    if noise_seed is not None:  # another measurement realisation of the same world and trajectory
        noise = dict(zip(_STREAMS, np.random.SeedSequence(noise_seed).spawn(len(_STREAMS))))
        streams.update({k: noise[k] for k in NOISE_STREAMS})
    return streams


def _hash_extra(config: SimConfig, seed_value, noise_value) -> tuple[dict, dict]:
    """(the config as the sequence's meta holds it, what the content hash covers besides the arrays)."""
    config_dict = asdict(config)
    if not config.pixel_noise_per_triplet:  # absent at its default, so the hashes of existing drives stay
        del config_dict["pixel_noise_per_triplet"]
    extra = {"config": config_dict, "seed": seed_value}
    if noise_value is not None:  # absent otherwise, so the hashes of existing drives stay
        extra["noise_seed"] = noise_value
    if config.output == "images":
        from avio.sim.render import RENDER_VERSION  # OpenCV only when rendering

        extra["render_version"] = RENDER_VERSION
    return config_dict, extra


def simulate(config: SimConfig, seed: int | tuple[int, ...], image_dir: str | Path | None = None,
             true_calibration: Calibration | None = None, noise_seed: int | tuple[int, ...] | None = None) -> Sequence:
    """A simulated drive: a pure function of (config, seed[, truth]).

    seed: an int or a tuple of ints (numpy SeedSequence entropy; e.g. ``(data_seed, drive)``
    for independent drives of one camera).
    image_dir: cache folder for rendered images (needed when ``config.output == "images"``;
    images go to ``image_dir/sim_<hash>/`` and are reused when already there).
    true_calibration: the camera's true calibration (batch of 1); None draws it from the seed and
    ``config.calibration_error``. Give the calibration drive's truth to simulate another drive
    (independent world, noise and biases) of the same camera.
    noise_seed: None, or the entropy of the measurement streams (NOISE_STREAMS): the same
    trajectory, world and camera as ``seed`` gives, with independent IMU noise and biases, pixel
    noise, outliers and feature selection (a noise realisation of that drive).
    """
    return simulate_world(config, seed, image_dir, true_calibration, noise_seed)[0]
