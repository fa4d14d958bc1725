"""The paper's figures rebuilt from run records of a VIO problem (PNG, matplotlib Agg).

- ``convergence_<optimizer>_evals.png`` / ``_seconds.png``: each calibration variable's
  best-so-far value against evaluations and wall seconds, one line per seed, the stop point
  marked, truth and reference as horizontal lines (the paper's Figs. 5–7);
- ``trajectories_<drive>.png``: top-down ground truth, VIO with the reference, AVIO (Figs. 9, 12);
- ``errors_<drive>.png``: position, velocity and attitude errors over time (Figs. 11, 13);
- ``profile.png`` + ``profile.csv``: the objective along each variable, others at the truth
  (or the reference when the truth is unknown) — see :func:`objective_profile`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from avio.metrics import pose_errors  # noqa: E402
from avio.sequence import Calibration  # noqa: E402
from bench.problems.vio import VioRmseProblem  # noqa: E402
from bench.records import eval_log_frame  # noqa: E402

_PNG = {"metadata": {"Software": None}, "dpi": 110}


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, **_PNG)
    plt.close(fig)
    return path


def _grid(n: int):
    cols = 5 if n > 6 else n
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, axes.flat


def best_so_far_values(job_dir: Path, names: list[str]) -> pd.DataFrame:
    """Per evaluation of one job: ``eval``, ``t_end_s`` and the variables of the best point so far."""
    log = eval_log_frame(job_dir, names)
    if log.empty:
        return log
    best_row = log["f"].where(np.isfinite(log["f"]), np.inf).expanding().apply(np.argmin, raw=True).astype(int)
    values = log[[f"x.{n}" for n in names]].to_numpy()[best_row.to_numpy()]
    out = pd.DataFrame(values, columns=names)
    out.insert(0, "t_end_s", log["t_end_s"].to_numpy())
    out.insert(0, "eval", log["eval"].to_numpy())
    return out


def convergence_figures(problem: VioRmseProblem, records: list[dict], out: Path) -> list[Path]:
    """Figs. 5–7: per optimiser, every variable's best-so-far value against evaluations and seconds."""
    names = list(problem.space.names)
    written = []
    for optimizer in sorted({r["optimizer"] for r in records}):
        runs = [(r["seed"], best_so_far_values(Path(r["job_dir"]), names))
                for r in sorted(records, key=lambda r: r["seed"]) if r["optimizer"] == optimizer]
        for axis, label in (("eval", "evaluations"), ("t_end_s", "wall seconds")):
            fig, axes = _grid(len(names))
            for i, (ax, name) in enumerate(zip(axes, names)):
                for seed, frame in runs:
                    if frame.empty:
                        continue
                    line, = ax.plot(frame[axis], frame[name], lw=0.9, alpha=0.8)
                    ax.plot(frame[axis].iloc[-1], frame[name].iloc[-1], "x", color=line.get_color())
                ax.axhline(problem.space.reference[i], color="0.5", ls=":", lw=1, label="reference")
                if problem.truth is not None:
                    ax.axhline(problem.truth[i], color="k", ls="--", lw=1, label="truth")
                ax.set_title(f"{name} ({problem.space.units[i]})", fontsize=9)
                ax.set_xlabel(label, fontsize=8)
                ax.tick_params(labelsize=7)
            axes[0].legend(fontsize=7)
            fig.suptitle(f"{optimizer}: best-so-far calibration per seed (x = stop)", fontsize=10)
            fig.tight_layout()
            stem = "evals" if axis == "eval" else "seconds"
            written.append(_save(fig, out / f"convergence_{optimizer}_{stem}.png"))
    return written


def median_seed_calibration(problem: VioRmseProblem, records: list[dict], optimizer: str) -> Calibration:
    """The calibration of the optimiser's median seed (by best f): a typical outcome, not the luckiest."""
    rows = sorted((r for r in records if r["optimizer"] == optimizer), key=lambda r: (r["best_f"], r["seed"]))
    return problem.calibration_space.decode(np.array([rows[(len(rows) - 1) // 2]["best_x"]]))


def trajectory_figures(problem: VioRmseProblem, avio: Calibration, label: str, out: Path) -> list[Path]:
    """Figs. 9/12 and 11/13 on the calibration drive and the held-out drive."""
    written = []
    drives = [("calibration", problem.sequence)] + ([("holdout", problem.holdout)] if problem.holdout else [])
    for which, sequence in drives:
        batch = Calibration.stack([sequence.reference_calibration, avio])
        result = problem.run_filter(batch, sequence)
        errors = pose_errors(result, sequence.truth)
        fig, ax = plt.subplots(figsize=(6.5, 5.5))
        gt = sequence.truth.p_world_imu_m
        ax.plot(gt[:, 0], gt[:, 1], "k-", lw=2, label="ground truth")
        for k, (name, style) in enumerate((("VIO reference", "--"), (f"AVIO ({label})", "-"))):
            p = result.p_world_imu_m[k]
            ax.plot(p[:, 0], p[:, 1], style, lw=1.2, label=f"{name}: RMSE {errors['position_rmse'][k]:.2f} m")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{which} drive {sequence.name} ({sequence.path_length_m():.0f} m), top-down")
        ax.legend(fontsize=8)
        written.append(_save(fig, out / f"trajectories_{which}.png"))

        t = sequence.frame_t_s - sequence.frame_t_s[0]
        fig, axes = plt.subplots(3, 1, figsize=(7.5, 7), sharex=True)
        for ax, (state, unit) in zip(axes, (("position", "m"), ("velocity", "m/s"), ("attitude", "deg"))):
            for k, name in enumerate(("VIO reference", f"AVIO ({label})")):
                ax.plot(t, errors[f"{state}_errors"][k], lw=1, label=name)
            ax.set_ylabel(f"{state} error ({unit})")
        axes[0].legend(fontsize=8)
        axes[-1].set_xlabel("time (s)")
        fig.suptitle(f"errors over time, {which} drive {sequence.name}")
        fig.tight_layout()
        written.append(_save(fig, out / f"errors_{which}.png"))
    return written


def objective_profile(problem: VioRmseProblem, n_points: int = 21) -> pd.DataFrame:
    """The objective along each variable across its bounds, the others at the truth (or reference).

    One batch of ``n_points * d`` evaluations. Columns: variable, unit, value, offset (value minus
    the anchor), f, and the calibration errors when the truth is known.
    """
    anchor = problem.truth if problem.truth is not None else problem.space.reference
    rows, labels = [], []
    for i, name in enumerate(problem.space.names):
        grid = np.unique(np.r_[np.linspace(problem.space.lower[i], problem.space.upper[i], n_points), anchor[i]])
        X = np.tile(anchor, (len(grid), 1))
        X[:, i] = grid
        rows.append(X)
        labels += [(name, problem.space.units[i], v, v - anchor[i]) for v in grid]
    f, metrics = problem.evaluate(np.concatenate(rows))
    frame = pd.DataFrame(labels, columns=["variable", "unit", "value", "offset"])
    frame["f"] = f
    for key, values in metrics.items():
        frame[key] = values
    return frame


def profile_figure(profile: pd.DataFrame, out: Path, anchor_label: str) -> Path:
    names = list(dict.fromkeys(profile["variable"]))
    fig, axes = _grid(len(names))
    for ax, name in zip(axes, names):
        part = profile[profile["variable"] == name]
        ax.plot(part["value"], part["f"], ".-", lw=1)
        anchor = part.loc[part["offset"].abs().idxmin(), "value"]
        ax.axvline(anchor, color="k", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_title(f"{name} ({part['unit'].iloc[0]})", fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle(f"position RMSE (m) along each variable, others at the {anchor_label} (dashed)", fontsize=10)
    fig.tight_layout()
    return _save(fig, out)
