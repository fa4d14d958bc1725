"""The paper's figures rebuilt from run records and stored filter artifacts (``bench.report.paper.artifacts``).

Each figure is a PNG (150 dpi) with a PDF beside it (``bench.figures.save_figure``), drawn on
``matplotlib.figure.Figure`` (no pyplot, no backend switch at import):

- ``convergence_<optimizer>_evals.png`` / ``_seconds.png``: each calibration variable's
  best-so-far value against evaluations and wall seconds, one line per seed (legend), the
  stop point marked, truth and reference as horizontal lines (the paper's Figs. 5–7);
- ``trajectories_<drive>.png``: top-down ground truth and the VIO with the reference, the
  truth and the leading optimiser's median-run calibration, each coloured by its position
  error on one shared scale (as evo draws them; the paper's Figs. 9, 12);
- ``errors_<drive>.png``: position, velocity and attitude errors over time (Figs. 11, 13);
- ``profile.png``: the objective along each variable on a linear scale, the others at the
  truth (or the reference when the truth is unknown), truth and reference marked.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure

from bench.records import EVAL_LOG, read_eval_log
from bench.report.curves import incumbent_index
from bench.report.figures import figure_key, is_current, save_figure

STATE_UNITS = (("position", "m"), ("velocity", "m/s"), ("attitude", "deg"))


def _grid(n: int, width: float = 3.2, height: float = 2.6):
    cols = 5 if n > 6 else max(n, 1)
    rows = int(np.ceil(n / cols))
    fig = Figure(figsize=(width * cols, height * rows + 0.6))
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


def best_so_far_values(job_dir: Path, names: list[str]) -> pd.DataFrame:
    """Per evaluation of one job: ``eval`` (1-based), ``t_end_s`` (its batch's end) and the
    variables of the incumbent (best point so far; ties keep the earlier point)."""
    entries = read_eval_log(job_dir)
    entries = [e for e in entries if len(e["f"])]
    if not entries:
        return pd.DataFrame(columns=["eval", "t_end_s", *names])
    X = np.concatenate([np.asarray(e["X"], float).reshape(len(e["f"]), -1) for e in entries])
    f = np.concatenate([np.asarray(e["f"], float) for e in entries])
    t = np.concatenate([np.full(len(e["f"]), float(e["t_end_s"])) for e in entries])
    out = pd.DataFrame(X[incumbent_index(f)], columns=names)
    out.insert(0, "t_end_s", t)
    out.insert(0, "eval", np.arange(1, len(f) + 1))
    return out


def convergence_figures(space: dict, records: list[dict], out: Path, log=None) -> list[Path]:
    """Figs. 5–7: per optimiser, every variable's best-so-far value against evaluations and
    seconds, one line per seed. ``space``: the artifacts manifest's ``space``; ``log``: called
    with a line before each figure is drawn (a few seconds each)."""
    names, units = space["names"], space["units"]
    written = []
    for optimizer in sorted({r["optimizer"] for r in records}):
        mine = [r for r in sorted(records, key=lambda r: int(r["seed"])) if r["optimizer"] == optimizer]
        logs = [hashlib.sha256((Path(r["job_dir"]) / EVAL_LOG).read_bytes()).hexdigest()
                if (Path(r["job_dir"]) / EVAL_LOG).exists() else "" for r in mine]
        runs = None
        for axis, label in (("eval", "evaluations"), ("t_end_s", "wall seconds")):
            stem = "evals" if axis == "eval" else "seconds"
            path = out / f"convergence_{optimizer}_{stem}.png"
            key = figure_key("convergence", axis, space, [(int(r["seed"]), h) for r, h in zip(mine, logs)])
            if is_current(path, key):
                written.append(path)
                continue
            if log:
                log(f"  convergence figure {path.name}")
            if runs is None:
                runs = [(int(r["seed"]), best_so_far_values(Path(r["job_dir"]), names)) for r in mine]
            fig, axes = _grid(len(names))
            for i, (ax, name) in enumerate(zip(axes, names)):
                for seed, frame in runs:
                    if frame.empty:
                        continue
                    # the incumbent changes rarely: draw its steps, not every evaluation
                    change = np.r_[True, np.any(np.diff(frame[names].to_numpy(), axis=0) != 0, axis=1)]
                    change[-1] = True
                    part = frame[change]
                    line, = ax.plot(part[axis], part[name], lw=0.9, alpha=0.85, drawstyle="steps-post",
                                    label=f"seed {seed}")
                    ax.plot(part[axis].iloc[-1], part[name].iloc[-1], "x", color=line.get_color())
                ax.axhline(space["reference"][i], color="0.5", ls=":", lw=1, label="reference")
                if space.get("truth") is not None:
                    ax.axhline(space["truth"][i], color="k", ls="--", lw=1, label="truth")
                ax.set_title(f"{name} ({units[i]})", fontsize=9)
                ax.set_xlabel(label, fontsize=8)
                ax.tick_params(labelsize=7)
            handles, labels = axes[0].get_legend_handles_labels()
            fig.legend(handles, labels, loc="upper right", fontsize=7, ncol=min(len(labels), 8))
            fig.suptitle(f"{optimizer}: best-so-far calibration per seed (x = stop)", fontsize=10, x=0.3)
            fig.subplots_adjust(left=0.05, right=0.99, bottom=0.1, top=0.84, wspace=0.35, hspace=0.55)
            written.append(save_figure(fig, path, key=key))
    return written


def _shown(trajectories: dict, leader: str) -> list[int]:
    """Indices of the reference, the truth and the leader's median run among the stored trajectories."""
    labels = [str(v) for v in trajectories["labels"]]
    return [i for i, label in enumerate(labels)
            if label in ("reference", "truth") or label.startswith(f"AVIO {leader} (")]


def _label(label: str) -> str:
    return {"reference": "VIO reference", "truth": "VIO truth calibration"}.get(label, label)


def trajectory_figures(artifacts, leader: str, out: Path) -> list[Path]:
    """Figs. 9/12 and 11/13 for each stored drive: top-down trajectories coloured by position
    error, and the errors over time, for the reference, the truth and ``leader``'s median run."""
    written = []
    cmap = colormaps["viridis"]
    for which, traj in artifacts.trajectories.items():
        drive = artifacts.manifest["drives"][which]
        shown = _shown(traj, leader)
        paths = [out / f"trajectories_{which}.png", out / f"errors_{which}.png"]
        key = figure_key("trajectories", artifacts.manifest["key"], which, leader)
        if all(is_current(p, key) for p in paths):
            written += paths
            continue
        gt = traj["p_true"]
        norm = Normalize(0.0, float(np.nanmax(traj["e_position"][shown])) if shown else 1.0)
        fig = Figure(figsize=(5.2 * max(len(shown), 1), 5.2))
        axes = np.atleast_1d(fig.subplots(1, max(len(shown), 1)))
        for ax, k in zip(axes, shown):
            p = traj["p_est"][k]
            e = traj["e_position"][k]
            ax.plot(gt[:, 0], gt[:, 1], color="0.6", lw=2.5, ls="--", label="ground truth")
            segments = np.stack([p[:-1, :2], p[1:, :2]], axis=1)
            lc = LineCollection(segments, cmap=cmap, norm=norm, linewidths=1.6)
            lc.set_array(0.5 * (e[:-1] + e[1:]))
            ax.add_collection(lc)
            ax.plot(*p[0, :2], "o", color="k", ms=4)
            rmse = float(np.sqrt(np.mean(e ** 2)))
            ax.set_title(f"{_label(str(traj['labels'][k]))}\nposition RMSE {rmse:.2f} m", fontsize=9)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel("x (m)")
            ax.legend(fontsize=7, loc="best")
        axes[0].set_ylabel("y (m)")
        fig.colorbar(lc, ax=list(axes), label="position error (m)", shrink=0.85)
        fig.suptitle(f"{which} drive {drive['name']} ({drive['path_length_m']:.0f} m), top-down, "
                     f"coloured by position error", fontsize=10)
        written.append(save_figure(fig, paths[0], key=key))

        fig = Figure(figsize=(8, 7))
        axes = fig.subplots(3, 1, sharex=True)
        for ax, (state, unit) in zip(axes, STATE_UNITS):
            for k in shown:
                ax.plot(traj["t_s"], traj[f"e_{state}"][k], lw=1, label=_label(str(traj["labels"][k])))
            ax.set_ylabel(f"{state} error ({unit})")
            ax.grid(True, alpha=0.3)
        axes[0].legend(fontsize=8)
        axes[-1].set_xlabel("time (s)")
        fig.suptitle(f"errors over time, {which} drive {drive['name']}")
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.08, top=0.93, hspace=0.12)
        written.append(save_figure(fig, paths[1], key=key))
    return written


def profile_figure(profile: pd.DataFrame, space: dict, out: Path, objective: str = "position_rmse") -> Path:
    """The objective along each variable on a linear scale (a 3 mm change looks like one),
    the others at the truth (dashed, black) or the reference (dotted, grey) when the truth is
    unknown; a truth outside the bounds is drawn where it is and flagged in the panel title."""
    names = list(dict.fromkeys(profile["variable"]))
    key = figure_key("profile", profile, space, objective)
    if is_current(out, key):
        return Path(out)
    fig, axes = _grid(len(names))
    truth = space.get("truth")
    anchor = "truth" if truth is not None else "reference"
    for ax, name in zip(axes, names):
        i = space["names"].index(name)
        part = profile[profile["variable"] == name]
        ax.plot(part["value"], part["f"], ".-", lw=1, ms=3)
        ax.axvline(space["reference"][i], color="0.5", ls=":", lw=1.2, label="reference")
        outside = ""
        if truth is not None:
            ax.axvline(truth[i], color="k", ls="--", lw=0.9, label="truth")
            if not space["truth_in_bounds"][i]:
                outside = " — truth outside the bounds"
        ax.axvspan(space["lower"][i], space["upper"][i], color="0.92", zorder=0)
        ax.set_title(f"{name} ({part['unit'].iloc[0]}){outside}", fontsize=8,
                     color="firebrick" if outside else "black")
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(axis="y", useOffset=False)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"objective ({objective}, linear scale) along each variable, the others at the {anchor}; "
                 "grey band = the bounds", fontsize=10)
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.08, top=0.86, wspace=0.4, hspace=0.55)
    return save_figure(fig, out, key=key)
