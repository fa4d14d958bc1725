"""A problem whose data is missing says which file, and how to point at the data."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.problems import ProblemError, get

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.parametrize("name, missing", [("kitti00", "kitti00/KITTI_00_gt.txt"),
                                           ("kitti00_tracks", "kitti00/VO_stereo_factors00.txt"),
                                           ("euroc", "euroc_v1_01/kalibr_imucam_chain.yaml")])
def test_missing_data_names_the_file_and_both_ways_to_point_at_it(name, missing, tmp_path, monkeypatch):
    for how in ("data_dir", "AVIO_DATA"):
        params = {"data_dir": str(tmp_path)} if how == "data_dir" else {}
        monkeypatch.setenv("AVIO_DATA", str(tmp_path))
        with pytest.raises(ProblemError) as err:
            get(name).preflight(**params)
        message = str(err.value)
        assert f"{tmp_path / missing}: " in message and "not found" in message
        assert "AVIO_DATA=" in message and "problem.params.data_dir=" in message
        assert "python -m bench.data" in message


def test_kitti_raw_missing_drive_says_how_to_point_at_one(tmp_path):
    with pytest.raises(ProblemError, match=r"no oxts/data\); point problem\.params\.path at"):
        get("kitti_raw").Params(path=str(tmp_path)).check_data()


def test_the_command_line_exits_2_with_the_hint(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "AVIO_DATA": str(tmp_path / "empty")}
    proc = subprocess.run([sys.executable, "-m", "bench", "problem=kitti00", "optimizer=random", "instance=0",
                           f"hydra.sweep.dir={tmp_path / 'sweep'}"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    said = proc.stdout + proc.stderr  # the preflight's message (its stream is not this test's concern)
    assert "kitti00/KITTI_00_gt.txt" in said and "AVIO_DATA=" in said and "problem.params.data_dir=" in said
    assert not (tmp_path / "sweep").exists()
