"""The dataset-neutral VIO calibration objective: a batch of candidate calibrations, run through
the filter over one or more calibration drives of one camera, scored by the chosen objective.

A data source is one small module beside this one (``synthetic.py``, ``kitti00.py``, ``kitti_raw.py``,
``euroc.py``): a frozen parameters dataclass derived from :class:`VioParams` (its defaults are the
yaml's defaults; it validates itself in one place), whose :meth:`VioParams.check_data` makes the
cheap data checks the preflight runs before any work and whose :meth:`VioParams.build` returns the
:class:`Drives`; and a two-line :class:`VioProblem` subclass registered under the yaml's name.

Objectives (``objective=``), all batched and pooled over the calibration drives:

- ``position_rmse`` (default; the paper's Eq. 11-12, what Tables 1-3 use): the position RMSE
  against the ground truth over all frames of all drives, metres.
- ``innovation_nll``: the filter's own measurement likelihood, the negative log-likelihood of
  its innovations per residual (avio.objectives.innovation_nll), dimensionless: a sum of
  per-feature marginal likelihoods.
- ``innovation_nll_joint``: the joint likelihood of each update's stacked innovations with
  their full covariance (avio.objectives.innovation_nll_joint), per residual.
- ``innovation_nll_adjusted``: the joint likelihood with each update's ``1/2 tr(S^-1 R)`` added,
  which cancels its tilt at the truth along fy (avio.objectives, docs/model.md Eq. 55b).

Both likelihoods default to imposed decisions, ``filter: {outlier_decisions: reference_all}``
(:data:`LIKELIHOOD_FILTER_DEFAULTS`; ``filter: {outlier_decisions: own}`` restores the filters' own):
the same features for every calibration, so the objective is smooth and comparable across a batch.
The evidence (studies/identifiability/README.md): 4 drives, 7 free, seeds 0-19, innovation_nll's
median rotation error 0.27 deg with reference_all against 0.50 deg with its own decisions (paired
Wilcoxon p = 0.009), principal point 2.4 against 4.6 px (p = 0.009). ``position_rmse`` keeps the
filters' own decisions (the paper's filter). Adding a source: docs/guide/adding-a-problem.md.

A filter that diverges gets ``divergence_penalty_m * (2 - k_div / N)`` (in the objective's
units): finite, worse than any regular value, worse the earlier it diverged.

Beside f, every evaluation reports, uncharged: every objective, the trajectory errors, the drift
(avio.metrics.drift_metrics: KITTI t_rel/r_rel, per-metre drift, the largest one-frame jump), the
filter's NIS per degree of freedom, and the calibration errors against the truth (or a trusted
reference such as Kalibr) when the source knows one (avio.calibration)."""

from __future__ import annotations

import types
import typing
from dataclasses import asdict, dataclass, fields
from typing import ClassVar

import numpy as np

from avio.calibration import Calibration, calibration_errors
from avio.filter.batch import run, threads
from avio.filter.config import FilterConfig, FilterError, FilterResult
from avio.filter.prepare import prepare
from avio.metrics import drift_metrics, pose_errors
from avio.objectives import (
    OBJECTIVES,
    innovation_nll,
    innovation_nll_joint,
    pooled_position_rmse,
    scored_frames,
    unused_feature_nll,
)
from avio.sequence import Sequence
from bench.problems._data_dir import DATA_HINT, checked_data, default_data_dir, require_data, with_data_hint
from bench.problems.base import ProblemError
from bench.problems.calibration_space import make_calibration_space
from bench.space import SpaceError

#: FilterConfig settings a likelihood objective uses unless the user's ``filter`` sets them (module docstring)
LIKELIHOOD_FILTER_DEFAULTS = {"outlier_decisions": "reference_all"}


def _tuples(d: dict | None) -> dict:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in (d or {}).items()}


def filter_config(params: dict | None) -> FilterConfig:
    """A FilterConfig from a config dict; unknown keys are an error naming the valid ones."""
    valid = {f.name for f in fields(FilterConfig)}
    unknown = set(params or {}) - valid
    if unknown:
        raise ProblemError(f"filter: unknown setting(s) {sorted(unknown)}; valid: {', '.join(sorted(valid))}")
    try:
        return FilterConfig(**_tuples(params))
    except (FilterError, TypeError) as err:
        raise ProblemError(f"filter: {err}") from None


@dataclass(frozen=True)
class Drives:
    """What a data source builds: the calibration drives (one camera, one or more drives or noise
    realisations) and the held-out drive (same camera, independent data; never seen by the
    optimiser), each a Sequence with tracks."""

    calibration: tuple[Sequence, ...]
    holdout: Sequence | None = None


def _plain(value):
    """A config value as plain data (tuples for lists, dicts kept) for the dataclass fields."""
    if isinstance(value, list):
        return tuple(_plain(v) for v in value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _type_ok(value, hint) -> bool:
    """Whether a config value fits a field's type hint (the simple hints these dataclasses use)."""
    origin = typing.get_origin(hint)
    if hint is typing.Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, h) for h in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is bool:
        return isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    if origin is tuple or hint is tuple:
        if not isinstance(value, tuple):
            return False
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_type_ok(v, args[0]) for v in value)
        return not args or (len(args) == len(value) and all(_type_ok(v, a) for v, a in zip(value, args)))
    if origin is dict or hint is dict:
        return isinstance(value, dict)
    return True


@dataclass(frozen=True)
class VioParams:
    """The settings every VIO problem shares (the same keys in every VIO problem's yaml).

    space: "paper" (Table 1 bounds, ZYX Euler deg) or "local" (rotation vector and offsets
        around the source's nominal calibration, intrinsics range from that nominal).
    with_time_offset: add the camera-IMU time offset td (s) as a variable.
    bounds: {variable: [lower, upper]} overrides.
    filter: FilterConfig overrides (avio/filter/config.py), e.g. {pixel_sigma_px: 0.5}, over the
        source's ``filter_defaults``.
    divergence_penalty_m: objective of a diverged filter, ``penalty * (2 - k_div / N)``, in the
        objective's units (> 0).
    objective: one of avio.objectives.OBJECTIVES.
    fixed: variables frozen at the nominal (reported as frozen, not calibrated).
    tie_focal: fy = fx (square pixels; fy is then not a variable).
    """

    #: FilterConfig settings the source needs (e.g. a smaller min_parallax_m for a slow rig),
    #: merged under the user's ``filter`` overrides.
    filter_defaults: ClassVar[dict] = {}

    space: str = "local"
    with_time_offset: bool = False
    bounds: dict | None = None
    filter: dict | None = None
    divergence_penalty_m: float = 1000.0
    objective: str = "position_rmse"
    fixed: tuple[str, ...] = ()
    tie_focal: bool = False

    @classmethod
    def from_config(cls, params: dict | None) -> "VioParams":
        """The parameters from a config dict: unknown keys and wrongly typed values are a
        ProblemError naming the key and what it must be; then :meth:`validate`."""
        params = dict(params or {})
        hints = typing.get_type_hints(cls)
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(params) - set(names))
        if unknown:
            raise ProblemError(f"unknown setting(s) {unknown}; valid: {', '.join(names)}")
        values = {}
        for key, value in params.items():
            value = _plain(value)
            if isinstance(value, int) and not isinstance(value, bool) and hints[key] is float:
                value = float(value)
            if not _type_ok(value, hints[key]):
                raise ProblemError(f"{key} = {value!r}: must be {_hint_text(hints[key])}")
            values[key] = value
        obj = cls(**values)
        try:
            obj.validate()
        except ProblemError as err:  # a source's nominal may read its data (euroc: the Kalibr file)
            raise with_data_hint(obj, err) from None
        return obj

    def validate(self) -> None:
        """Raise ProblemError naming the first invalid setting (cheap: no data is read)."""
        if not (np.isfinite(self.divergence_penalty_m) and self.divergence_penalty_m > 0):
            raise ProblemError(f"divergence_penalty_m = {self.divergence_penalty_m}: must be a finite number > 0 "
                               "(a non-positive penalty would rank diverged filters best)")
        if self.objective not in OBJECTIVES:
            raise ProblemError(f"objective = {self.objective!r}: valid: {', '.join(OBJECTIVES)}")
        filter_config(self.filter_settings())
        self.space_for(self.nominal_for_checks(), self.image_size_for_checks())

    def filter_settings(self) -> dict:
        """The filter's settings: the source's defaults, a likelihood's (imposed decisions), then the
        user's overrides."""
        likelihood = LIKELIHOOD_FILTER_DEFAULTS if self.objective != "position_rmse" else {}
        return {**self.filter_defaults, **likelihood, **(self.filter or {})}

    # --- what a source provides ----------------------------------------------------------

    def nominal_for_checks(self) -> Calibration:
        """The nominal calibration the space is built around, known without reading data (for
        the preflight's space check); sources override."""
        from avio.reference import kitti_2011_10_03_calibration

        return kitti_2011_10_03_calibration()

    def image_size_for_checks(self) -> tuple[int, int]:
        from avio.reference import IMAGE_SIZE_PX

        return IMAGE_SIZE_PX

    def check_data(self) -> None:
        """Cheap checks of the data the problem will read (files, windows); ProblemError."""

    def build(self) -> Drives:
        raise ProblemError(f"{type(self).__name__} does not build drives")  # every source overrides

    # --- shared helpers ----------------------------------------------------------------------

    def space_for(self, nominal: Calibration, image_size_px: tuple[int, int]):
        try:
            return make_calibration_space(self.space, nominal, with_time_offset=self.with_time_offset,
                                          bounds=self.bounds, image_size_px=image_size_px, fixed=self.fixed,
                                          tie_focal=self.tie_focal)
        except SpaceError as err:
            raise ProblemError(str(err)) from None

    def as_config(self) -> dict:
        return asdict(self)


def _hint_text(hint) -> str:
    text = str(hint).replace("typing.", "")
    return {"<class 'float'>": "a number", "<class 'int'>": "an integer", "<class 'bool'>": "true or false",
            "<class 'str'>": "a string"}.get(text, text)


class VioProblem:
    """The VIO calibration objective over a source's drives (module docstring).

    ``Params``: the source's VioParams subclass; ``name``: the registered name. Build with the
    yaml's params (``Cls(**params)``); ``Cls.preflight(**params)`` validates them and checks the
    data cheaply without building anything.
    """

    Params: type[VioParams] = VioParams
    name = "vio"

    def __init__(self, **params) -> None:
        self.params = checked_data(self.Params.from_config(params))
        drives = self.params.build()
        self._setup(drives)

    @classmethod
    def preflight(cls, **params) -> None:
        checked_data(cls.Params.from_config(params))

    def _setup(self, drives: Drives) -> None:
        p = self.params
        if not drives.calibration:
            raise ProblemError(f"{self.name}: no calibration drive")
        first = drives.calibration[0]
        for seq in drives.calibration[1:] + ((drives.holdout,) if drives.holdout is not None else ()):
            same_truth = (seq.truth_calibration is None) == (first.truth_calibration is None) and (
                first.truth_calibration is None or _same_calibration(seq.truth_calibration, first.truth_calibration))
            if not (same_truth and _same_calibration(seq.reference_calibration, first.reference_calibration)):
                raise ProblemError(f"{self.name}: drive {seq.name!r} has another camera than {first.name!r}")
        self.drives = tuple(drives.calibration)
        self.sequence, self.holdout = first, drives.holdout
        self.calibration_space = p.space_for(first.reference_calibration, first.image_size_px)
        self.space = self.calibration_space.space
        self.filter_config = filter_config(p.filter_settings())
        self.divergence_penalty_m = float(p.divergence_penalty_m)
        self.objective = p.objective
        # Calibration-free work, once per sequence: prepare() and the likelihood's scored frames,
        # cached by id for the problem's own drives and held-out drive only (the problem keeps
        # them alive, so their ids cannot pass to another sequence); see prepared().
        self._prepared = {id(s): prepare(s, self.filter_config) for s in self.drives}
        self._scored = {}
        truth = first.truth_calibration
        self.truth = None if truth is None else self.calibration_space.encode(truth)[0]
        # the exact calibrations: a round trip through Euler angles near gimbal lock moves R by ~1e-7
        anchors = Calibration.stack([first.reference_calibration] + ([] if truth is None else [truth]))
        f_anchor, _ = self.score(anchors)
        self.f_reference = float(f_anchor[0])
        self.f_truth = None if self.truth is None else float(f_anchor[1])

    @property
    def f_unit(self) -> str:
        """The unit of f (records and the leaderboard carry it)."""
        return "m" if self.objective == "position_rmse" else "nats per residual"  # both likelihoods

    @property
    def filter_threads(self) -> int:  # the threads a batch runs on now: the record's machine.filter_threads
        return threads()

    @property
    def reference_calibration(self) -> Calibration:
        return self.sequence.reference_calibration

    @property
    def identity(self) -> dict:
        return {"sequence": self.sequence.name, "n_frames": self.sequence.n_frames,
                "sequence_meta": {k: v for k, v in self.sequence.meta.items() if np.ndim(v) == 0},
                "drives": [{"name": s.name, "n_frames": s.n_frames, "content_hash": s.meta.get("content_hash")}
                           for s in self.drives],
                "holdout": None if self.holdout is None else self.holdout.name,
                "holdout_content_hash": None if self.holdout is None else self.holdout.meta.get("content_hash"),
                "objective": self.objective, "outlier_decisions": self.filter_config.outlier_decisions}

    def _owns(self, sequence: Sequence) -> bool:
        return sequence is self.holdout or any(sequence is s for s in self.drives)

    def prepared(self, sequence: Sequence):
        """avio.filter.prepare of ``sequence`` with this problem's filter settings: cached for the
        problem's own drives and held-out drive, computed afresh for any other sequence (a cache
        by id would hand a later sequence that reuses a freed id the wrong preparation)."""
        if not self._owns(sequence):
            return prepare(sequence, self.filter_config)
        if id(sequence) not in self._prepared:
            self._prepared[id(sequence)] = prepare(sequence, self.filter_config)
        return self._prepared[id(sequence)]

    def _scored_frames(self, sequence: Sequence) -> np.ndarray:
        if not self._owns(sequence):
            return scored_frames(sequence)
        if id(sequence) not in self._scored:
            self._scored[id(sequence)] = scored_frames(sequence)
        return self._scored[id(sequence)]

    def run_filter(self, calibrations: Calibration, sequence: Sequence | None = None) -> FilterResult:
        """All filters of the batch over ``sequence`` (default: the first calibration drive)."""
        sequence = sequence or self.sequence
        return run(sequence, calibrations, self.filter_config, prepared=self.prepared(sequence))

    def score(self, cal: Calibration, drives: tuple[Sequence, ...] | None = None
              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """f (n,) of the calibrations over ``drives`` (default: the calibration drives; one batch
        per drive) and the uncharged metrics (n,) beside it."""
        drives = self.drives if drives is None else drives
        return self.score_results([self.run_filter(cal, s) for s in drives], drives)

    def score_results(self, results: list, drives: tuple[Sequence, ...]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`score` from the FilterResults (one per drive, in order) of runs already made
        (for callers that also read the results, e.g. studies/identifiability/line_scan.py's decision counts)."""
        truths = [s.truth for s in drives]
        penalty = self.divergence_penalty_m
        rmse = pooled_position_rmse(results, truths, penalty)
        scored = [self._scored_frames(s) for s in drives]
        nll, nis_per_dof = innovation_nll(results, penalty, scored)
        c = self.filter_config
        unused = unused_feature_nll(c.pixel_sigma_px, c.chi2_threshold)
        joint = innovation_nll_joint(results, penalty, unused, scored)
        adjusted = innovation_nll_joint(results, penalty, unused, scored, adjusted=True)
        f = {"position_rmse": rmse, "innovation_nll": nll, "innovation_nll_joint": joint,
             "innovation_nll_adjusted": adjusted}[self.objective]
        errors = [pose_errors(r, s.truth) for r, s in zip(results, drives)]
        frames = np.array([s.n_frames for s in drives], float)

        def pooled(key: str) -> np.ndarray:  # RMS over every frame of every drive
            return np.sqrt(sum(w * e[key] ** 2 for w, e in zip(frames, errors)) / frames.sum())

        metrics = {"diverged": np.any([r.diverged for r in results], axis=0).astype(float),
                   "position_rmse_m": rmse, "innovation_nll": nll,
                   "innovation_nll_joint": joint, "nis_per_dof": nis_per_dof,
                   "velocity_rmse_mps": pooled("velocity_rmse"), "attitude_rmse_deg": pooled("attitude_rmse")}
        drift = [drift_metrics(r.p_world_imu_m, r.R_world_imu, s.truth) for r, s in zip(results, drives)]
        for key in drift[0]:  # the drives' mean drift; the largest jump of any drive
            values = np.stack([d[key] for d in drift])
            metrics[key] = values.max(axis=0) if key == "max_jump_m" else values.mean(axis=0)
        return f, metrics

    def evaluate(self, X: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """f (n,) (the chosen objective over the calibration drives) and metrics (n,): both
        objectives, trajectory errors, NIS/dof, divergence flags, calibration errors when known."""
        X = self.space.check(X)
        cal = self.calibration_space.decode(X)
        f, metrics = self.score(cal)
        truth = self.sequence.truth_calibration
        if truth is not None:
            errs = calibration_errors(cal, truth)
            if "td" not in self.space.names:
                errs.pop("time_offset_error_ms")
            metrics.update(errs)
        return f, metrics


def _same_calibration(a: Calibration, b: Calibration) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in Calibration.__dataclass_fields__)


__all__ = ["DATA_HINT", "Drives", "VioParams", "VioProblem", "default_data_dir",
           "filter_config", "require_data"]
