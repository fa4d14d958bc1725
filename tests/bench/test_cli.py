"""The front door: `python -m bench` sweeps as typed, validates before work, writes the leaderboard."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]


def bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.slow
def test_sweep_runs_exactly_as_typed_and_writes_the_leaderboard(tmp_path):
    out = tmp_path / "sweep"
    proc = bench("problem=sphere", "optimizer=random,one_plus_one", "seed=range(3)", "budget.evals=64",
                 f"hydra.sweep.dir={out}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    records = sorted(p.relative_to(out).as_posix() for p in out.rglob("record.json"))
    assert records == [f"sphere/{o}/seed{s}/record.json" for o in ("one_plus_one", "random") for s in range(3)]
    board = pd.read_csv(out / "report" / "leaderboard.csv")
    assert set(board["optimizer"]) == {"random", "one_plus_one"}
    assert (board["n_runs"] == 3).all() and (board["n_failed"] == 0).all()
    assert "Leaderboard" in proc.stdout and str(out) in proc.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["optimizer=random,nope"], "Could not find 'optimizer/nope'"),
        (["problem=nope"], "Could not find 'problem/nope'"),
        (["budget.evals=0"], "budget.evals must be a positive integer, got 0"),
        (["budget.evals=null", "budget.seconds=null"], "set budget.evals or budget.seconds"),
        (["budget.seconds=-1"], "budget.seconds must be a positive number"),
        (["budget.seconds=nan"], "budget.seconds is nan"),
        (["seed=abc"], "seed must be an integer"),
    ],
)
def test_bad_input_fails_before_any_work_with_one_clear_message(tmp_path, args, message, capsys):
    from bench.__main__ import main

    with pytest.raises(SystemExit) as exit_info:
        main(["optimizer=random", *args, f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    assert exit_info.value.code == 2
    out = capsys.readouterr()
    assert message in out.out
    assert "Traceback" not in out.out + out.err
    assert not (tmp_path / "sweep").exists()  # nothing ran


def test_the_command_line_exits_2_without_a_traceback(tmp_path):
    proc = bench("optimizer=nope", f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=tmp_path)
    assert proc.returncode == 2 and "Available options in 'optimizer'" in proc.stdout
    assert "Traceback" not in proc.stdout + proc.stderr and not (tmp_path / "sweep").exists()


def _code_blocks(markdown: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", markdown, flags=re.S)


def test_readme_plugin_example_is_the_shipped_plugin():
    readme = (ROOT / "README.md").read_text()
    assert (ROOT / "optimizers" / "one_plus_one.py").read_text() in _code_blocks(readme, "python")
    assert (ROOT / "conf" / "optimizer" / "one_plus_one.yaml").read_text() in _code_blocks(readme, "yaml")
