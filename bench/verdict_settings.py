"""The report's verdict settings (``verdict:`` in bench/conf/config.yaml), checked in one place.

The sweep checks them at its start, before any work (``bench.run.preflight``: a bad setting is
one message naming the key, exit 2); the report checks them again on the records it reads
(``bench.report``), which is why they live here, importable by both without ``bench.run``
importing ``bench.report``. Settings (docs/guide/verdicts.md):

- ``key``: the record key runs are paired on (default ``instance``): a top-level key of the job
  config (``instance``, ``seed``) or a dotted path in it (``problem.params.data_seed``).
- ``test``: the post-hoc test, one of :data:`TESTS` (``bench.report.verdict.POSTHOCS``).
- ``family``: ``leader`` (each optimiser against the leader, k - 1 tests) or ``all`` (every pair).
- ``alpha``: the family-wise error rate, in (0, 1).
- ``rope``: the region of practical equivalence of the objective, a number >= 0 in the
  objective's units; or a section of them, each named ``default`` (the objective of every
  problem not named), a problem name (its objective) or a calibration error of
  :data:`METRIC_ROPES` (in that error's units).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from bench.errors import BenchError

TESTS = ("wilcoxon", "nemenyi", "conover")
FAMILIES = ("leader", "all")
#: calibration errors a ROPE can be set for (avio.calibration.calibration_errors and ray_error_deg)
METRIC_ROPES = ("rotation_error_deg", "focal_error_px", "principal_point_error_px", "translation_error_cm",
                "time_offset_error_ms", "ray_error_deg")
SETTINGS = ("key", "test", "family", "alpha", "rope")
_PROBLEM_YAMLS = Path(__file__).resolve().parent / "conf" / "problem"


class VerdictSettingsError(BenchError):
    """A verdict setting is invalid; the message names the key (``verdict.<setting>``) and the valid choices."""


@dataclass(frozen=True)
class VerdictSettings:
    """The checked settings: ``key`` (pairing), ``test``, ``family``, ``alpha`` and ``rope``
    ({name: value >= 0}; see the module docstring)."""

    key: str = "instance"
    test: str = "wilcoxon"
    family: str = "leader"
    alpha: float = 0.05
    rope: Mapping[str, float] = field(default_factory=lambda: {"default": 0.0})  # a number is {"default": it}

    def objective_rope(self, problem: str) -> float:
        """The ROPE of ``problem``'s objective (its own entry, else ``default``, else 0), objective units."""
        return float(self.rope.get(problem, self.rope.get("default", 0.0)))

    def objective_ropes(self, problems: Iterable[str]) -> dict[str, float]:
        """``{problem: rope}`` for ``bench.report.verdict.verdicts(rope=...)``."""
        return {p: self.objective_rope(p) for p in problems}

    def metric_rope(self, metric: str) -> float | None:
        """The ROPE of a calibration error (its units), or None when none is set."""
        value = self.rope.get(metric)
        return None if value is None else float(value)


def known_problems() -> set[str]:
    """Names a ROPE may carry: the registered problems and the problem yamls."""
    from bench import problems

    return set(problems.available()) | {p.stem for p in _PROBLEM_YAMLS.glob("*.yaml")}


def record_column(key: str, columns: Iterable[str]) -> str | None:
    """The column of a flattened record frame (``bench.records.load_records``) that holds the
    pairing ``key``: ``key`` itself (a top-level record field such as ``instance``), else
    ``config.<key>``; None when the records lack it."""
    columns = set(columns)
    return next((c for c in (key, f"config.{key}") if c in columns), None)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_rope(rope, problems: set[str] | None) -> dict[str, float]:
    scalar = isinstance(rope, (int, float)) and not isinstance(rope, bool)
    if scalar:
        rope = {"default": rope}  # one value for every problem's objective
    if not isinstance(rope, Mapping):
        raise VerdictSettingsError(f"verdict.rope must be a number >= 0 or a section {{name: value >= 0}} (default, a "
                                   f"problem, or one of {', '.join(METRIC_ROPES)}), got {rope!r}")
    known = (known_problems() if problems is None else set(problems)) | {"default", *METRIC_ROPES}
    out = {}
    for name, value in rope.items():
        if name not in known:
            raise VerdictSettingsError(f"verdict.rope.{name}: unknown ROPE name; valid: default, a problem "
                                       f"({', '.join(sorted(known - {'default', *METRIC_ROPES}))}) or a calibration "
                                       f"error ({', '.join(METRIC_ROPES)})")
        if not _number(value) or value < 0:
            where = "verdict.rope" if scalar else f"verdict.rope.{name}"
            raise VerdictSettingsError(f"{where} = {value!r}: must be a finite number >= 0 (in the units of what it "
                                       "is the ROPE of)")
        out[str(name)] = float(value)
    return out


def verdict_settings(node: Mapping | None, keys: Iterable[str] | None = None,
                     problems: Iterable[str] | None = None) -> VerdictSettings:
    """The checked settings of a ``verdict:`` section (None: the defaults).

    keys: the keys a pairing may use (the dotted paths of a job config, or a record frame's
    columns; ``record_column`` decides), None to skip that check. problems: the names a ROPE may
    carry besides ``default`` and :data:`METRIC_ROPES` (None: ``known_problems()``).
    VerdictSettingsError naming the first invalid key.
    """
    node = dict(node or {})
    unknown = sorted(set(node) - set(SETTINGS))
    if unknown:
        raise VerdictSettingsError(f"verdict: unknown setting(s) {unknown}; valid: {', '.join(SETTINGS)}")
    settings = {**{k: getattr(VerdictSettings(), k) for k in SETTINGS}, **node}
    if settings["test"] not in TESTS:
        raise VerdictSettingsError(f"verdict.test = {settings['test']!r}: unknown test; valid: {', '.join(TESTS)}")
    if settings["family"] not in FAMILIES:
        raise VerdictSettingsError(f"verdict.family = {settings['family']!r}: valid: {', '.join(FAMILIES)}")
    if not _number(settings["alpha"]) or not 0 < settings["alpha"] < 1:
        raise VerdictSettingsError(f"verdict.alpha = {settings['alpha']!r}: must be a number in (0, 1)")
    key = settings["key"]
    if not isinstance(key, str) or not key:
        raise VerdictSettingsError(f"verdict.key = {key!r}: must be the name of a record key, e.g. instance")
    if keys is not None and record_column(key, keys) is None:
        raise VerdictSettingsError(f"verdict.key = {key!r}: the records lack this key, so runs cannot be paired on "
                                   "it; pair on instance (every optimiser once per instance)")
    return VerdictSettings(key, settings["test"], settings["family"], float(settings["alpha"]),
                           _check_rope(settings["rope"], None if problems is None else set(problems)))


__all__ = ["FAMILIES", "METRIC_ROPES", "TESTS", "VerdictSettings", "VerdictSettingsError", "known_problems",
           "record_column", "verdict_settings"]
