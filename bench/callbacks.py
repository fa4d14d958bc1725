"""Hydra callbacks: rebuild the leaderboard and report when a sweep ends."""

from __future__ import annotations

import logging
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

log = logging.getLogger(__name__)


class SweepReport(Callback):
    """At the end of a sweep, run ``bench.report`` over the sweep folder and say where things are.

    Hydra hands this only the config, so the results are read back from the job folders.
    """

    def on_multirun_end(self, config: DictConfig, **kwargs) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        if not config.get("report", True):
            print(f"Records: {sweep_dir}")
            return
        from bench.report import build_report

        out = build_report([sweep_dir], sweep_dir / "report")
        print(f"Records:     {sweep_dir}")
        print(f"Leaderboard: {out.parent / 'leaderboard.csv' if out.is_file() else out / 'leaderboard.csv'}")
        print(f"Report:      {out}")
