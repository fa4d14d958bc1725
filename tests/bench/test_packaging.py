"""The wheel is complete: built from the checkout, installed in a fresh environment elsewhere, it
runs a sweep through its console script (configs included, nothing read from the checkout)."""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    # as a user builds it: pip's isolated build environment with pyproject's setuptools
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    (path,) = out.glob("avio_bench-*.whl")
    return path


@pytest.mark.slow
def test_wheel_holds_the_configs_and_the_console_script(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    shipped = {n for n in names if n.startswith("bench/conf/") and n.endswith(".yaml")}
    expected = {p.relative_to(REPO).as_posix() for p in (REPO / "bench" / "conf").rglob("*.yaml")}
    assert expected and shipped == expected
    entry = next(n for n in names if n.endswith("entry_points.txt"))
    assert "avio-bench = bench.__main__:cli" in zipfile.ZipFile(wheel).read(entry).decode()
    # the bench_slurm/bench_local launchers: a module of the hydra_plugins namespace package
    assert "hydra_plugins/bench_launcher/launcher.py" in names and "hydra_plugins/__init__.py" not in names


@pytest.mark.slow
def test_installed_wheel_runs_a_small_sweep_outside_the_checkout(wheel, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    new_site = next((venv / "lib").glob("python*/site-packages"))
    # the dependencies come from this environment's site-packages, appended to the path (a plain
    # path entry: its .pth files, among them the checkout's editable install, are not run)
    (new_site / "deps.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    python = venv / "bin" / "python"
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    where = subprocess.run([str(python), "-c", "import bench, avio, optimizers; print(bench.__file__)"],
                           cwd=cwd, env=env, capture_output=True, text=True, timeout=120, check=True)
    assert Path(where.stdout.strip()).is_relative_to(venv)
    sweep = tmp_path / "sweep"
    done = subprocess.run([str(venv / "bin" / "avio-bench"), "problem=sphere", "optimizer=random", "budget.evals=20",
                           "instance=0", "report=false", f"hydra.sweep.dir={sweep}"],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    (record,) = sweep.rglob("record.json")
    data = json.loads(record.read_text())
    assert data["status"] == "ok" and data["n_evals"] == 20 and data["problem"] == "sphere"
    assert not any(cwd.iterdir()) or not (cwd / "bench").exists()
