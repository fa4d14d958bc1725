"""``--version`` prints avio-bench's version (not Hydra's) and exits 0."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

from bench import version

ROOT = Path(__file__).resolve().parents[2]
EXPECTED = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def test_version_is_the_pyprojects():
    assert version() == EXPECTED


def test_python_m_bench_version_prints_ours_and_exits_0(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # this checkout's bench, whatever the venv installed
    proc = subprocess.run([sys.executable, "-m", "bench", "--version"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == f"avio-bench {EXPECTED}"
    assert "Hydra" not in proc.stdout + proc.stderr
    assert not any(tmp_path.iterdir())  # nothing run, nothing written


def test_version_wins_over_overrides(capsys):
    from bench.__main__ import main

    main(["problem=sphere", "--version"])
    assert capsys.readouterr().out.strip() == f"avio-bench {EXPECTED}"


def test_without_a_pyproject_the_installed_metadata_answers(monkeypatch, tmp_path):
    import importlib.metadata

    import bench

    monkeypatch.setattr(bench, "__file__", str(tmp_path / "bench" / "__init__.py"))  # no pyproject.toml there
    monkeypatch.setattr(importlib.metadata, "version", lambda name: "9.9.9" if name == "avio-bench" else None)
    assert bench.version() == "9.9.9"
