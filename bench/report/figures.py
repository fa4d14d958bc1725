"""PNG figures of anytime curves and runtime ECDFs, one figure per problem, and the one saver
every report figure goes through.

Built on ``matplotlib.figure.Figure`` with the Agg canvas (no pyplot, no global state, no
display, no ``matplotlib.use``). Each figure is written as a PNG at ``DPI`` (for pages) and a
PDF beside it (vector, for papers); neither carries a timestamp or a software tag, so the same
data give the same bytes.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, NullFormatter

PNG_METADATA = {"Software": None}
PDF_METADATA = {"CreationDate": None, "Producer": None, "Creator": None}
DPI = 150
# Fixed margins instead of tight_layout, and plain-number tick labels instead of mathtext:
# both measured as most of the time of a report build.
MARGINS = {"left": 0.07, "right": 0.985, "bottom": 0.13, "top": 0.88, "wspace": 0.22}
PLAIN = FuncFormatter(lambda value, _: f"{value:g}")
AXIS_LABELS = {"evals": "evaluations", "seconds": "wall time (s)"}


KEY_FIELD = "avio-bench-key"  # PNG text chunk: what the figure was drawn from


def figure_key(*parts) -> str:
    """Hex SHA-256 of what a figure is drawn from (JSON-able parts, bytes, str or DataFrames) and of
    the drawing code (this module, ``bench.report.paper.figures`` and matplotlib's version).
    A DataFrame enters at 12 significant digits: values a report recomputes (the reference's errors)
    differ in the last bits between CPUs (numpy's SIMD paths), and no pixel does."""
    import matplotlib

    digest = hashlib.sha256(matplotlib.__version__.encode())
    here = Path(__file__).resolve().parent
    for module in (here / "figures.py", here / "paper" / "figures.py"):
        digest.update(module.read_bytes())
    for part in parts:
        if isinstance(part, pd.DataFrame):
            part = part.to_csv(index=False, float_format="%.12g", lineterminator="\n")
        digest.update(part if isinstance(part, bytes) else
                      (part if isinstance(part, str) else json.dumps(part, sort_keys=True, default=str)).encode())
        digest.update(b"\0")
    return digest.hexdigest()


def is_current(path: Path, key: str | None, pdf: bool = True) -> bool:
    """Whether ``path`` (and its PDF) already hold the figure drawn from ``key``: drawing is
    most of a report's time, and the same inputs give the same bytes, so it is skipped."""
    path = Path(path)
    if key is None or not path.is_file() or (pdf and not path.with_suffix(".pdf").is_file()):
        return False
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return image.text.get(KEY_FIELD) == key
    except (OSError, UnidentifiedImageError):
        return False


def save_figure(fig: Figure, path: Path, pdf: bool = True, key: str | None = None) -> Path:
    """Write ``fig`` to ``path`` (.png, at ``DPI``, with ``key`` in its metadata, see
    ``is_current``) and, with ``pdf``, the same figure as ``path`` with suffix .pdf; return the
    PNG's path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI, metadata={**PNG_METADATA, **({KEY_FIELD: key} if key else {})})
    if pdf:
        fig.savefig(path.with_suffix(".pdf"), metadata=PDF_METADATA)
    return path



def _colors(optimizers: list[str]) -> dict[str, tuple]:
    # A fixed palette keyed by sorted name: the same optimiser keeps its colour across figures.
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(optimizers) <= 10 else "tab20"]
    return {name: cmap(i % cmap.N) for i, name in enumerate(sorted(optimizers))}


def anytime_figure(curves: pd.DataFrame, problem: str, path: Path,
                   levels: dict[str, float] | None = None) -> Path:
    """Best-so-far f (median line, IQR band) vs evaluations and vs seconds for one problem.

    curves: ``bench.curves.anytime_curves`` rows for both axes (column ``axis``);
    levels: labelled horizontal reference lines in objective units (e.g. f at the truth and at
    the reference calibration); non-finite values are skipped.
    """
    levels = {k: v for k, v in (levels or {}).items() if v is not None and np.isfinite(v)}
    data = curves[curves["problem"] == problem]
    key = figure_key("anytime", problem, data, {k: float(v) for k, v in levels.items()})
    if is_current(path, key):
        return Path(path)
    colors, fig, axes = _panels_per_axis(data)
    for ax, axis in zip(axes, AXIS_LABELS):
        part = data[data["axis"] == axis]
        for optimizer, g in part.groupby("optimizer", sort=True):
            x = g["x"].to_numpy(float)
            # a marker where there are too few points for a visible step (one big batch)
            ax.step(x, g["median"], where="post", color=colors[optimizer], label=optimizer,
                    marker="o" if len(x) < 3 else None, markersize=4)
            ax.fill_between(x, g["q25"], g["q75"], step="post", color=colors[optimizer], alpha=0.2)
        for (label, value), style in zip(sorted(levels.items()), ("--", ":", "-.")):
            ax.axhline(value, color="0.3", linestyle=style, linewidth=1, label=label)
        y = np.append(part[["q25", "median", "q75"]].to_numpy(float).ravel(), list(levels.values()))
        _log_axes(ax, part["x"], y)
        ax.set_xlabel(AXIS_LABELS[axis])
        ax.set_ylabel("best objective so far (median, IQR)")
        ax.grid(True, which="both", alpha=0.3)
    return _finish(fig, axes, f"{problem}: anytime performance", path, key)


def _panels_per_axis(data: pd.DataFrame):
    """(a colour per optimiser, a figure, its two panels: against evaluations and against seconds)."""
    colors = _colors(list(data["optimizer"].unique()))
    fig = Figure(figsize=(11, 4.2))
    return colors, fig, fig.subplots(1, 2)


def _finish(fig, axes, title: str, path: Path, key: str) -> Path:
    """Legend (or notes), title and margins, then the figure saved with its key."""
    _legend_or_note(axes)
    fig.suptitle(title)
    fig.subplots_adjust(**MARGINS)
    return save_figure(fig, path, key=key)


def _legend_or_note(axes) -> None:
    """A legend on the first panel, or a note on each empty panel (e.g. every run failed)."""
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize="small")
    for ax in axes:
        if not ax.get_legend_handles_labels()[0]:
            ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center")


def _log_scale(ax, which: str, values: np.ndarray) -> None:
    """Put the x or y axis of ``ax`` on a log scale with plain-number labels."""
    getattr(ax, f"set_{which}scale")("log")
    axis = getattr(ax, f"{which}axis")
    axis.set_major_formatter(PLAIN)
    span = np.log10(values.max() / values.min()) if values.size else 0.0
    # label the minor ticks only when the range is too short to show a labelled decade
    axis.set_minor_formatter(PLAIN if span < 1.0 else NullFormatter())


def _log_axes(ax, x: pd.Series, y: np.ndarray) -> None:
    # Log scales only when every plotted value is positive; zero optima keep a linear axis.
    x = x.to_numpy(float)
    if len(x) and (x > 0).all():
        _log_scale(ax, "x", x)
    finite = y[np.isfinite(y)]
    if finite.size and (finite > 0).all() and finite.max() > 10 * finite.min():
        _log_scale(ax, "y", finite)


def ecdf_figure(ecdf: pd.DataFrame, problem: str, path: Path) -> Path:
    """Fraction of (run, target) pairs hit against evaluations and seconds for one problem.

    ecdf: ``bench.targets.ecdf`` rows for both axes (column ``axis``).
    """
    data = ecdf[ecdf["problem"] == problem]
    key = figure_key("ecdf", problem, data)
    if is_current(path, key):
        return Path(path)
    colors, fig, axes = _panels_per_axis(data)
    for ax, axis in zip(axes, AXIS_LABELS):
        part = data[data["axis"] == axis]
        for optimizer, g in part.groupby("optimizer", sort=True):
            ax.step(g["budget"], g["fraction"], where="post", color=colors[optimizer], label=optimizer,
                    marker="o" if len(g) < 3 else None, markersize=4)
        if len(part) and (part["budget"] > 0).all():
            _log_scale(ax, "x", part["budget"].to_numpy(float))
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel(AXIS_LABELS[axis])
        ax.set_ylabel("fraction of (run, target) pairs hit")
        ax.grid(True, which="both", alpha=0.3)
    return _finish(fig, axes, f"{problem}: runtime ECDF over all fixed targets", path, key)


def final_values_figure(frame: pd.DataFrame, problem: str, path: Path, unit: str = "",
                        reference: str = "reference") -> Path:
    """Box plot and strip of the final best f per optimiser (and the reference row) of one
    problem; frame: the objective's tidy ``problem, optimizer, <key>, value`` (``bench.report.paired``)."""
    data = frame[frame["problem"] == problem]
    key = figure_key("final", problem, data, unit)
    if is_current(path, key):
        return Path(path)
    order = data.groupby("optimizer")["value"].median().sort_values(kind="stable").index.tolist()
    colors = _colors([o for o in order if o != reference])
    fig = Figure(figsize=(max(5.0, 0.9 * len(order) + 2), 4.0))
    ax = fig.add_subplot()
    values = [data.loc[data["optimizer"] == o, "value"].dropna().to_numpy(float) for o in order]
    ax.boxplot(values, showfliers=False, widths=0.5)
    jitter = np.random.default_rng(0)  # a fixed spread of the strip: the same figure every build
    for i, (name, v) in enumerate(zip(order, values), start=1):
        ax.scatter(i + jitter.uniform(-0.15, 0.15, v.size), v, s=12, zorder=3,
                   color="k" if name == reference else colors[name], marker="*" if name == reference else "o")
    ax.set_xticks(range(1, len(order) + 1), order, rotation=30, ha="right")
    finite = np.concatenate(values) if values else np.array([])
    if finite.size and (finite > 0).all() and finite.max() > 10 * finite.min():
        _log_scale(ax, "y", finite)
    ax.set_ylabel(f"final best f{' (' + unit + ')' if unit else ''}")
    ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(f"{problem}: final values (one point per run; reference: star)")
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.25, top=0.9)
    return save_figure(fig, path, key=key)


def objective_error_figure(runs: pd.DataFrame, problem: str, errors: list[str], path: Path) -> Path:
    """Final best f against each calibration error (one panel per error, one point per job,
    coloured by optimiser), the reference calibration of each instance as a black star.
    runs: ``runs_table`` with ``m.<error>`` and, where known, ``ref.<error>`` columns."""
    data = runs[(runs["problem"] == problem) & runs["valid"]]
    cols = ["optimizer", "best_f", "f_reference", *[f"m.{e}" for e in errors],
            *[f"ref.{e}" for e in errors if f"ref.{e}" in data.columns]]
    key = figure_key("scatter", problem, data[cols])
    if is_current(path, key):
        return Path(path)
    colors = _colors(list(data["optimizer"].unique()))
    fig = Figure(figsize=(4.0 * max(1, len(errors)) + 1.0, 3.8))
    axes = np.atleast_1d(fig.subplots(1, max(1, len(errors)), sharey=True))
    for ax, error in zip(axes, errors):
        for name, g in data.groupby("optimizer", sort=True):
            ax.scatter(g[f"m.{error}"], g["best_f"], s=14, color=colors[name], label=name)
        if f"ref.{error}" in data.columns:
            ax.scatter(data[f"ref.{error}"], data["f_reference"], s=60, marker="*", color="k", label="reference")
        ax.set_xlabel(error)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("final best f")
    handles, labels = axes[0].get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    axes[0].legend(unique.values(), unique.keys(), fontsize="small")
    fig.suptitle(f"{problem}: objective against calibration error (one point per run)")
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.15, top=0.88, wspace=0.08)
    return save_figure(fig, path, key=key)
