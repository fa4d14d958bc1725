"""The report's paired verdicts: the objective and each calibration error, the reference calibration as a row.

A sweep answers two questions. The *optimisation question* compares the optimisers' final best
f; the *calibration question* (where the truth is known) compares how far their best points are
from the truth, one error at a time (``ERROR_ROPES``). Each question is a tidy frame
``problem, optimizer, <key>, value`` handed to ``bench.report.verdict.verdicts``: runs are paired
on the pairing key (``instance``, the sweep's unit of replication; records without it are paired
on ``seed``, and the report says so), failed runs are NaN (ranked last by ``verdicts``).

**The reference calibration** is a row named ``REFERENCE``: on each instance it scores the
records' ``f_reference`` (f at the reference calibration on that instance) and its own errors
(``reference_errors``), and it is compared paired on instances like an optimiser, twice: within
the family against the leader, and as the control of its own family (every optimiser against
the reference, Holm over k - 1 tests), so "better than the reference" is a tested claim.

**Incomplete designs.** Only instances on which every row of a problem has a run enter its
verdicts (a complete block design); how many were left out is counted (``Paired.dropped``).

**Settings** (``check_settings``): ``test`` (wilcoxon | nemenyi | conover), ``family`` (leader |
all), ``rope`` (a number >= 0 in the objective's units, or a mapping problem -> number),
``alpha`` in (0, 1), ``key`` (the record field to pair on); read from the sweep's config (the
records' ``config.verdict.*``, else ``multirun.yaml``'s ``verdict:``), the command line's options
overriding. Bad values: ``SettingsError`` naming the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from bench.errors import BenchError
from bench.report import resolution as res
from bench.report.verdict import POSTHOCS, Verdicts, verdicts
from bench.verdict_settings import METRIC_ROPES

REFERENCE = "reference"
OBJECTIVE = "best_f"
# ROPE of each calibration error, in its unit (issue 29: 0.05 deg, 0.5 px, 0.5 cm)
ERROR_ROPES = {"rotation_error_deg": 0.05, "focal_error_px": 0.5, "principal_point_error_px": 0.5,
               "translation_error_cm": 0.5, "ray_error_deg": 0.05}
FALLBACK_KEY = "seed"
SEED_NOTE = "runs are not paired on instances; seeds used as blocks"
INSTANCE_SEED = "instance/seed"
INSTANCE_SEED_NOTE = ("several seeds per instance: runs are paired on (instance, seed), so the blocks are repeats "
                      "on shared instances, not independent instances")
SETTING_KEYS = ("test", "family", "rope", "alpha", "key")


class SettingsError(BenchError):
    """A verdict setting is invalid; the message names the key."""


@dataclass(frozen=True)
class VerdictSettings:
    """How the report decides (see the module doc); ``key_given``: the key was asked for, not defaulted."""

    test: str = "wilcoxon"
    family: str = "leader"
    rope: float | Mapping[str, float] = 0.0
    alpha: float = 0.05
    key: str = "instance"
    key_given: bool = False


def _number(name: str, value) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise SettingsError(f"verdict.{name} must be a number, got {value!r}") from None
    if not np.isfinite(out):
        raise SettingsError(f"verdict.{name} must be finite, got {value!r}")
    return out


def check_settings(raw: Mapping, problems: list[str] | None = None) -> VerdictSettings:
    """``raw`` (test, family, rope, alpha, key; any may be missing) as checked VerdictSettings;
    ``problems``: the names a ROPE mapping may use (plain names or the leaderboard's labels)."""
    raw = {k: v for k, v in dict(raw).items() if v is not None}
    unknown = sorted(set(raw) - set(SETTING_KEYS))
    if unknown:
        raise SettingsError(f"verdict.{unknown[0]}: unknown setting; settings are test, family, rope, alpha, key")
    test, family = str(raw.get("test", "wilcoxon")), str(raw.get("family", "leader"))
    if test not in POSTHOCS:
        raise SettingsError(f"verdict.test must be one of {', '.join(POSTHOCS)}, got {test!r}")
    if family not in res.FAMILIES:
        raise SettingsError(f"verdict.family must be one of {', '.join(res.FAMILIES)}, got {family!r}")
    alpha = _number("alpha", raw.get("alpha", 0.05))
    if not 0 < alpha < 1:
        raise SettingsError(f"verdict.alpha must be in (0, 1), got {raw.get('alpha')!r}")
    rope = raw.get("rope", 0.0)
    if isinstance(rope, Mapping):
        rope = {str(k): _number(f"rope.{k}", v) for k, v in rope.items()}
        values = rope.items()
    else:
        rope = _number("rope", rope)
        values = [("", rope)]
    for name, value in values:
        if value < 0:
            raise SettingsError(f"verdict.rope{'.' + name if name else ''} must be >= 0, got {value!r}")
    if isinstance(rope, dict) and problems is not None:  # also "default" and the calibration errors' names
        bad = sorted(set(rope) - set(problems) - {"default"} - set(METRIC_ROPES))
        if bad:
            raise SettingsError(f"verdict.rope.{bad[0]}: no such problem in the records; problems: "
                                f"{', '.join(sorted(set(problems)))}")
    key = str(raw.get("key", "instance"))
    return VerdictSettings(test, family, rope, alpha, key, "key" in raw)


def sweep_settings(roots: list[Path], records: pd.DataFrame) -> dict:
    """The ``verdict:`` settings the sweep ran with: the records' ``config.verdict.*`` (first
    record that has them), else the first root's ``multirun.yaml``; {} when neither says. Only
    ``SETTING_KEYS`` are read: other keys of the sweep's group are the sweep's business."""
    cols = [c for c in records.columns if c.startswith("config.verdict.")]
    out: dict = {}
    for col in cols:
        values = records[col].dropna()
        if len(values):
            parts = col[len("config.verdict."):].split(".", 1)
            value = values.iloc[0]
            if len(parts) == 2:
                out.setdefault(parts[0], {})[parts[1]] = value
            else:
                out[parts[0]] = value
    if out:
        return {k: v for k, v in out.items() if k in SETTING_KEYS}
    import yaml

    for root in roots:
        path = Path(root) / "multirun.yaml"
        if path.is_file():
            try:
                verdict = (yaml.safe_load(path.read_text()) or {}).get("verdict")
            except yaml.YAMLError:
                continue
            if isinstance(verdict, Mapping):
                return {k: v for k, v in verdict.items() if k in SETTING_KEYS}
    return {}


def pairing_key(runs: pd.DataFrame, settings: VerdictSettings) -> tuple[str, str]:
    """(the column to pair on, a note for the report's first lines or ""). A key asked for (on
    the command line or in the sweep's config) that the records lack is a SettingsError; the
    default ``instance``, not asked for, falls back to ``seed`` for records without it."""
    key = settings.key
    if key in runs.columns and runs[key].notna().all():
        if key == "instance" and "seed" in runs.columns and runs.duplicated(["problem", "optimizer", key]).any():
            return INSTANCE_SEED, INSTANCE_SEED_NOTE  # several seeds per instance: (instance, seed) blocks
        return key, ""
    if settings.key_given and key in runs.columns:
        raise SettingsError(f"verdict.key: some records lack the field {key!r} to pair on")
    if settings.key_given:
        raise SettingsError(f"verdict.key: the records have no field {key!r} to pair on")
    return FALLBACK_KEY, SEED_NOTE


def _rotation(names: list[str], x: np.ndarray):
    """scipy Rotation of a space point, or None when its rotation variables are not all free."""
    from scipy.spatial.transform import Rotation

    col = dict(zip(names, x))
    if {"roll", "pitch", "yaw"} <= set(col):  # Eq. 9: R = Rz(yaw) Ry(pitch) Rx(roll)
        return Rotation.from_euler("ZYX", [col["yaw"], col["pitch"], col["roll"]], degrees=True)
    if {"rx", "ry", "rz"} <= set(col):  # a rotation vector (deg) applied to the nominal on the left
        return Rotation.from_rotvec(np.radians([col["rx"], col["ry"], col["rz"]]))
    return None


def reference_errors(record: Mapping) -> dict[str, float]:
    """The reference calibration's errors against the truth for one (flattened) record:
    ``reference_metrics.<name>`` when the record has them, else what its space point and
    ``truth_x`` give (focal, principal point, rotation, lever arm when all their variables are
    free; the ray error needs the image size and is never computed here); {} without truth."""
    given = {k[len("reference_metrics."):]: float(v) for k, v in record.items()
             if k.startswith("reference_metrics.") and v is not None and np.isfinite(float(v))}
    if given:
        return given
    names, truth, ref = record.get("space.names"), record.get("truth_x"), record.get("space.reference")
    if not isinstance(names, list) or not isinstance(truth, list) or not isinstance(ref, list):
        return {}
    names, t, r = list(names), np.asarray(truth, float), np.asarray(ref, float)
    d = dict(zip(names, t - r))
    out = {}
    if {"fx", "fy"} <= set(d):
        out["focal_error_px"] = float(max(abs(d["fx"]), abs(d["fy"])))
    if {"cx", "cy"} <= set(d):
        out["principal_point_error_px"] = float(max(abs(d["cx"]), abs(d["cy"])))
    for trio in (("tx", "ty", "tz"), ("dx", "dy", "dz")):
        if set(trio) <= set(d):
            out["translation_error_cm"] = float(100.0 * np.linalg.norm([d[n] for n in trio]))
    rt, rr = _rotation(names, t), _rotation(names, r)
    if rt is not None and rr is not None:
        out["rotation_error_deg"] = float(np.degrees((rt * rr.inv()).magnitude()))
    return out


def add_reference_errors(runs: pd.DataFrame, records: pd.DataFrame) -> pd.DataFrame:
    """``runs`` with ``ref.<error>`` columns (the reference's errors on each run's instance)."""
    by_job = {str(r["job_dir"]): reference_errors(r) for r in records.to_dict("records")}
    names = sorted({n for errs in by_job.values() for n in errs})
    extra = {f"ref.{n}": runs["job_dir"].map(lambda j, n=n: by_job.get(j, {}).get(n, np.nan)).astype(float)
             for n in names}
    return runs.assign(**extra)


def questions(runs: pd.DataFrame, settings_rope=None) -> dict[str, tuple[str, str | None, float | None]]:
    """question -> (value column of the optimisers, column of the reference row or None, ROPE or
    None for the objective's own): the objective, and each calibration error the runs carry."""
    out = {OBJECTIVE: (OBJECTIVE, "f_reference", None)}
    for name, rope in ERROR_ROPES.items():
        if isinstance(settings_rope, Mapping) and name in settings_rope:  # the sweep's own ROPE
            rope = float(settings_rope[name])
        col = f"m.{name}"
        if col in runs.columns and runs[col].notna().any():
            ref = f"ref.{name}" if f"ref.{name}" in runs.columns and runs[f"ref.{name}"].notna().any() else None
            out[name] = (col, ref, rope)
    return out


def tidy(runs: pd.DataFrame, key: str, column: str, reference: str | None) -> tuple[pd.DataFrame, dict]:
    """(``problem, optimizer, <key>, value`` over complete blocks, {problem: instances left out}).
    Failed runs are NaN; the reference row takes the first finite ``reference`` value of each
    (problem, key)."""
    value = runs[column].where(runs["valid"])
    frame = pd.DataFrame({"problem": runs["problem"], "optimizer": runs["optimizer"], key: runs[key],
                          "value": value})
    if reference is not None:
        ref = (runs.dropna(subset=[reference]).sort_values(["problem", key, "job_dir"], kind="stable")
               .groupby(["problem", key], sort=True)[reference].first().rename("value").reset_index())
        frame = pd.concat([frame, ref.assign(optimizer=REFERENCE)], ignore_index=True)
    parts, dropped = [], {}
    for problem, rows in frame.groupby("problem", sort=True):
        counts = rows.groupby(key)["optimizer"].nunique()
        complete = counts.index[counts == rows["optimizer"].nunique()]
        dropped[problem] = int(len(counts) - len(complete))
        parts.append(rows[rows[key].isin(complete)])
    return pd.concat(parts, ignore_index=True)[["problem", "optimizer", key, "value"]], dropped


@dataclass
class Paired:
    """The verdicts of every question: ``by_question[q]`` (against the leader, or all pairs) and
    ``vs_reference[q]`` (every optimiser against the reference, where it has a row)."""

    key: str
    note: str
    settings: VerdictSettings
    by_question: dict[str, Verdicts] = field(default_factory=dict)
    vs_reference: dict[str, Verdicts] = field(default_factory=dict)
    dropped: dict[str, dict] = field(default_factory=dict)


def _rope_of(settings: VerdictSettings, runs: pd.DataFrame, problems: list[str]) -> float | dict:
    if not isinstance(settings.rope, Mapping):
        return settings.rope
    names = runs.drop_duplicates("problem").set_index("problem")["problem_name"]
    default = settings.rope.get("default", 0.0)
    # a ROPE given for a plain problem name holds for each of its labelled settings
    return {p: settings.rope.get(p, settings.rope.get(str(names.get(p, p)), default)) for p in problems}


def paired_verdicts(runs: pd.DataFrame, settings: VerdictSettings, seed: int = 0,
                    cap: int = res.N_CAP) -> Paired:
    """Every question's verdicts (module doc) from ``runs`` (``runs_table`` + ``add_reference_errors``)."""
    key, note = pairing_key(runs, settings)
    out = Paired(key, note, settings)
    for question, (column, reference, rope) in questions(runs, settings.rope).items():
        if question != OBJECTIVE:  # only the problems whose runs carry this error (the truth is known)
            known = runs.groupby("problem")[column].transform(lambda v: v.notna().any())
            sub = runs[known]
        else:
            sub = runs
        frame, dropped = tidy(sub, key, column, reference) if len(sub) else (pd.DataFrame(), {})
        if frame.empty:
            continue
        problems = sorted(frame["problem"].unique())
        rope = _rope_of(settings, sub, problems) if rope is None else rope
        common = dict(key=key, rope=rope, family=settings.family, posthoc_test=settings.test,
                      alpha=settings.alpha, seed=seed, cap=cap)
        out.by_question[question] = verdicts(frame, **common)
        out.dropped[question] = dropped
        if reference is not None:
            out.vs_reference[question] = verdicts(frame, **{**common, "family": "leader"}, against=REFERENCE)
    return out


PAGE_COLUMNS = ["optimizer", "mean rank", "median f", "verdict vs leader", "p (Holm)", "P(practically equal)",
                "instances to decide", "vs reference", "calibration rank", "failed"]


def ranks_of(v: Verdicts, problem: str) -> pd.Series:
    """Mean rank per row (optimiser or reference) of one problem of a question's verdicts."""
    return v.ranks[v.ranks["problem"] == problem].set_index("optimizer")["mean_rank"]


def calibration_ranks(paired: Paired, problem: str) -> pd.Series:
    """Mean over the calibration errors of each row's mean rank per error (empty without truth)."""
    errors = [q for q, v in paired.by_question.items() if q != OBJECTIVE and problem in set(v.ranks["problem"])]
    if not errors:
        return pd.Series(dtype=float)
    return pd.concat([ranks_of(paired.by_question[q], problem) for q in errors], axis=1).mean(axis=1)


def _needed_text(n: float) -> str:
    return "" if np.isnan(n) else (f"> {res.N_CAP}" if np.isinf(n) else f"{int(n)}")


def _fmt(value) -> str:
    return "" if value is None or (isinstance(value, float) and np.isnan(value)) else f"{value:.4g}"


def page_leaderboard(paired: Paired, runs: pd.DataFrame, problem: str) -> pd.DataFrame:
    """The on-page leaderboard of one problem (``PAGE_COLUMNS``, at most 10; the full table is
    leaderboard.csv): every optimiser and the reference row, best mean rank first."""
    objective = paired.by_question.get(OBJECTIVE)
    if objective is None or problem not in set(objective.friedman["problem"]):
        return pd.DataFrame(columns=PAGE_COLUMNS)
    ranks = objective.ranks[objective.ranks["problem"] == problem].set_index("optimizer")
    leader = objective.friedman.set_index("problem").loc[problem, "leader"]
    comp = objective.comparisons
    comp = comp[comp["problem"] == problem] if not comp.empty else comp
    ref = paired.vs_reference.get(OBJECTIVE)
    ref = ref.comparisons[ref.comparisons["problem"] == problem].set_index("a") if ref and len(ref.comparisons) \
        else pd.DataFrame(columns=["verdict"])
    cal = calibration_ranks(paired, problem).rank(method="min")
    unit = runs.loc[runs["problem"] == problem, "f_unit"].iloc[0] if "f_unit" in runs.columns else ""
    rows = []
    for name in ranks.sort_values("mean_rank", kind="stable").index:
        mine = comp[(comp["a"] == name) & (comp["b"] == leader)] if len(comp) else comp
        flip = {"better": "worse", "worse": "better"}
        if len(comp) and mine.empty:
            mine = comp[(comp["b"] == name) & (comp["a"] == leader)].assign(
                verdict=lambda c: c["verdict"].map(lambda v: flip.get(v, v)))
        one = mine.iloc[0] if len(mine) else None
        column = "f_reference" if name == REFERENCE else OBJECTIVE
        rows.append([name, round(float(ranks.loc[name, "mean_rank"]), 2),
                     (_fmt(runs.loc[(runs["problem"] == problem) & (runs["optimizer"] == name if name != REFERENCE
                                                                   else runs["valid"]), column].median())
                      + (f" {unit}" if unit else "")),
                     "leader" if name == leader else (one["verdict"] if one is not None else "untestable"),
                     _fmt(one["p_adjusted"]) if one is not None else "",
                     _fmt(one["p_equal"]) if one is not None else "",
                     (_needed_text(one["n_needed"]) if one is not None and one["verdict"] == "undecided" else ""),
                     "" if name == REFERENCE or name not in ref.index else ref.loc[name, "verdict"],
                     _fmt(cal.get(name, np.nan)), int(ranks.loc[name, "n_failed"])])
    return pd.DataFrame(rows, columns=PAGE_COLUMNS)
