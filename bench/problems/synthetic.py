"""``problem=synthetic``: simulated KITTI-like drives whose truth calibration is known.

``data_seed`` fixes the camera (its truth calibration: the KITTI reference plus a realistic
error) and the first calibration drive. Every further drive, and the held-out drive, is the
*same camera* with an independent world, trajectory, IMU noise and bias realisation (simulator
seed ``(data_seed, i)``, ``(data_seed, 1000)`` for the held-out drive), so that summing the
objective over drives averages out noise, and the held-out drive tests the calibration rather
than another camera. ``noise_realisations`` K > 1 adds, for each calibration drive, K - 1 noise
realisations of it: the same world and trajectory with independent IMU noise and biases, pixel
noise, outliers and feature selection (simulator noise seed ``(data_seed, i, 2000, r)``), so
that averaging the noise alone can be told from averaging the drives' geometry too.

A calibration drive can be the held-out drive only by sharing its preset and seed: with 1001 drives
or more, drive 1000 would be simulated with the held-out seed; that is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from avio.errors import AvioError
from avio.sequence import ImuNoise, Sequence
from bench.problems.base import ProblemError, register
from bench.problems.vio import Drives, VioParams, VioProblem, _tuples

PRESETS = ("paper_540m", "paper_928m", "full3d_540m")
HOLDOUT_SEED = 1000  # second entropy word of the held-out drive's seed: no calibration drive uses it
NOISE_WORD = 2000  # third entropy word of a noise realisation's seed (4 words: no drive's seed has as many)


def _sim_config(drive: str, sim: dict | None):
    from avio.sim.simulator import SimConfig

    if drive not in PRESETS:
        raise ProblemError(f"synthetic: unknown drive {drive!r}; valid: {', '.join(PRESETS)}")
    overrides = _tuples(sim)
    if isinstance(overrides.get("imu_noise"), dict):
        overrides["imu_noise"] = ImuNoise(**overrides["imu_noise"])
    try:
        config = getattr(SimConfig, drive)(**overrides)
        config.validate()
    except TypeError as err:
        raise ProblemError(f"sim: {err}") from None
    except AvioError as err:  # SimulatorError, or a trajectory's or camera's error
        raise ProblemError(f"sim: {err}") from None
    return config


@dataclass(frozen=True)
class SyntheticParams(VioParams):
    """drives: the calibration drives (presets of avio.sim.simulator.SimConfig: paper_540m = ~540 m
    in 78 s, flat city with a stop; paper_928m = ~928 m in 115 s with hills; full3d_540m = ~540 m in
    78 s on the full3d trajectory, rotation about every axis), all of one camera;
    holdout: the held-out preset or None; data_seed: the camera and the drives (>= 0);
    sim: SimConfig overrides for every drive, e.g. {pixel_noise_px: 1.0}; noise_realisations:
    each calibration drive in this many noise realisations (>= 1; module docstring)."""

    space: str = "paper"
    drives: tuple[str, ...] = ("paper_540m",)
    holdout: str | None = "paper_928m"
    data_seed: int = 0
    sim: dict | None = None
    noise_realisations: int = 1

    def validate(self) -> None:
        if self.data_seed < 0:
            raise ProblemError(f"data_seed = {self.data_seed}: must be >= 0")
        if self.noise_realisations < 1:
            raise ProblemError(f"noise_realisations = {self.noise_realisations}: must be >= 1")
        if not self.drives:
            raise ProblemError("drives: at least one calibration drive")
        if self.holdout and len(self.drives) > HOLDOUT_SEED and self.drives[HOLDOUT_SEED] == self.holdout:
            # every other drive has a seed of its own, so only this one can be the held-out drive itself
            raise ProblemError(f"drives[{HOLDOUT_SEED}] = {self.holdout!r} is the held-out drive itself (the same "
                               f"preset and simulator seed ({self.data_seed}, {HOLDOUT_SEED})): the held-out score "
                               "must come from a drive the optimiser never sees; use fewer drives or set holdout: null")
        for name in self.drives + ((self.holdout,) if self.holdout else ()):
            _sim_config(name, self.sim)
        super().validate()

    def image_size_for_checks(self) -> tuple[int, int]:
        return tuple(_sim_config(self.drives[0], self.sim).image_size_px)

    def build(self) -> Drives:
        from avio.sim.cache import simulate_cached as simulate

        first = simulate(_sim_config(self.drives[0], self.sim), self.data_seed)
        camera = first.truth_calibration
        seeds = [self.data_seed] + [(self.data_seed, i) for i in range(1, len(self.drives))]
        more = [simulate(_sim_config(name, self.sim), seed, true_calibration=camera,
                         noise_seed=None if r == 0 else (self.data_seed, i, NOISE_WORD, r))
                for i, (name, seed) in enumerate(zip(self.drives, seeds))
                for r in range(self.noise_realisations) if i > 0 or r > 0]
        held: Sequence | None = None
        if self.holdout:
            held = simulate(_sim_config(self.holdout, self.sim), (self.data_seed, HOLDOUT_SEED),
                            true_calibration=camera)
        return Drives((first, *more), held)


@register("synthetic")
class Synthetic(VioProblem):
    """Simulated drives with a known truth (module docstring); the default problem."""

    Params = SyntheticParams
    name = "synthetic"
