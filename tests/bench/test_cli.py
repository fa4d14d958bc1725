"""The front door: `python -m bench` sweeps as typed, validates before work, writes the leaderboard."""

from __future__ import annotations

import os
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
    proc = bench("problem=sphere", "optimizer=random,one_plus_one", "instance=range(3)", "budget.evals=64",
                 f"hydra.sweep.dir={out}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    records = sorted(p.relative_to(out).as_posix() for p in out.rglob("record.json"))
    assert records == [f"sphere/{o}/i{s}/record.json" for o in ("one_plus_one", "random") for s in range(3)]
    board = pd.read_csv(out / "report" / "leaderboard.csv")
    assert set(board["optimizer"]) == {"random", "one_plus_one"}
    assert (board["n_runs"] == 3).all() and (board["n_failed"] == 0).all()
    assert "Leaderboard" in proc.stdout and str(out) in proc.stdout
    assert proc.stdout.strip().splitlines()[-1] == f"Report:      {out / 'report' / 'report.html'}"


@pytest.mark.parametrize(
    "args, message",
    [
        (["optimizer=random,nope"], "Could not find 'optimizer/nope'"),
        (["problem=nope"], "Could not find 'problem/nope'"),
        (["budget.evals=0"], "budget.evals must be a positive integer or null, got 0"),
        (["budget.evals=true"], "budget.evals must be a positive integer or null, got True"),
        (["seed=-1"], "seed must be an integer in [0, 2**63), got -1"),
        (["instance=-1"], "instance must be an integer in [0, 2**63) (the problem instance), got -1"),
        (["instance=1.5"], "instance must be an integer in [0, 2**63) (the problem instance), got 1.5"),
        (["instance=abc"], "instance must be an integer in [0, 2**63) (the problem instance), got 'abc'"),
        (["instance=[0,-2]"], "instance must be an integer in [0, 2**63) (the problem instance), got [0, -2]"),
        (["verdict.test=tukey"], "verdict.test = 'tukey': unknown test; valid: wilcoxon, nemenyi, conover"),
        (["verdict.family=some"], "verdict.family = 'some': valid: leader, all"),
        (["verdict.alpha=0"], "verdict.alpha = 0: must be a number in (0, 1)"),
        (["verdict.rope={sphear:0.1}"], "verdict.rope.sphear: unknown ROPE name; valid: default, a problem ("),
        (["verdict.rope=-0.1"], "verdict.rope = -0.1: must be a finite number >= 0"),
        (["verdict.rope={focal_error_px:-1}"], "verdict.rope.focal_error_px = -1: must be a finite number >= 0"),
        (["verdict.key=camera"], "verdict.key = 'camera': the records lack this key, so runs cannot be paired on it"),
        (["+verdict.pairs=all"], "verdict: unknown setting(s) ['pairs']; valid: key, test, family, alpha, rope"),
        (["progress_every_s=abc"], "progress_every_s must be a positive number of seconds, got 'abc'"),
        (["threads=0"], "threads must be auto or an integer from 1 to"),
        (["threads=abc"], "threads must be auto or an integer from 1 to"),
        ([f"threads={(os.cpu_count() or 1) + 1}"], f"(this machine's cores), got {(os.cpu_count() or 1) + 1}"),
        (["threads=1,0"], "threads must be auto or an integer from 1 to"),  # swept: not in the identity
        (["filter_block=3"], "filter_block must be auto or one of 1, 2, 4, 8, got 3"),
        (["filter_block=eight"], "filter_block must be auto or one of 1, 2, 4, 8, got 'eight'"),
        (["log_metrics=all,some"], "log_metrics must be one of"),  # every job's, not once per identity
        (["plugins=[.evil]"], "plugins: '.evil' is not an absolute module name"),
        (["plugins=['']"], "plugins: '' is not an absolute module name"),
        (["plugins=[1]"], "plugins: 1 is not an absolute module name"),
        (["optimizer=pso", "optimizer.params.pop_size=0"], "optimizer.params: pso: pop_size must be an integer >= 2, got 0"),
        (["optimizer=pso", "optimizer.params.pop_size=-5"], "pso: pop_size must be an integer >= 2, got -5"),
        (["optimizer=pso", "optimizer.params.pop_size=1"], "pso: pop_size must be an integer >= 2, got 1"),
        (["optimizer=pso", "optimizer.params.pop_size=1.5"], "pso: pop_size must be an integer >= 2, got 1.5"),
        (["optimizer=pso", "optimizer.params.w=abc"], "pso: w must be a number in [0, inf), got 'abc'"),
        (["optimizer=ga", "optimizer.params.pop_size=1.5"], "ga: pop_size must be an integer >= 2, got 1.5"),
        (["optimizer=cmaes", "optimizer.params.population_size=1"],
         "cmaes: population_size must be an integer >= 2, got 1"),
        (["optimizer.params.batch_size=0"], "random: batch_size must be an integer >= 1, got 0"),
        (["problem=sphere", "problem.params.delay_s_per_batch=-1"],
         "problem=sphere: delay_s_per_batch must be >= 0, got -1"),  # found by building it, before any job
        (["+optimizer.params.speed=3"], "optimizer=random: cannot be built as RandomSearch(lower, upper, seed=, x0=, **params)"),
        (["budget.evals=null", "budget.seconds=null"], "set budget.evals or budget.seconds"),
        (["budget.seconds=-1"], "budget.seconds must be a positive number"),
        (["budget.seconds=nan"], "budget.seconds is nan"),
        (["seed=abc"], "seed must be an integer"),
        (["problem.params.bounds={fx:[740,700]}"], "variable 'fx': lower bound 740.0 is not below upper bound 700.0"),
        (["problem.params.space=polar"], "unknown space 'polar'"),
        (["problem.params.filter={gain:2}"], "filter: unknown setting(s) ['gain']"),
    ],
)
def test_bad_input_fails_before_any_work_with_one_clear_message(tmp_path, args, message, capsys):
    from bench.__main__ import main

    with pytest.raises(SystemExit) as exit_info:
        main(["optimizer=random", *args, f"hydra.sweep.dir={tmp_path / 'sweep'}"])
    assert exit_info.value.code == 2
    out = capsys.readouterr()
    assert message in out.err and out.out == ""  # bad input on stderr; stdout is for results
    assert "Traceback" not in out.out + out.err
    assert not (tmp_path / "sweep").exists()  # nothing ran


def test_the_command_line_exits_2_without_a_traceback(tmp_path):
    proc = bench("optimizer=nope", f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=tmp_path)
    assert proc.returncode == 2 and "Available options in 'optimizer'" in proc.stderr and proc.stdout == ""
    assert "Traceback" not in proc.stdout + proc.stderr and not (tmp_path / "sweep").exists()


def _code_blocks(markdown: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", markdown, flags=re.S)


def test_the_guides_plugin_example_is_the_shipped_plugin():
    guide = (ROOT / "docs" / "guide" / "adding-an-optimiser.md").read_text()
    assert (ROOT / "optimizers" / "one_plus_one.py").read_text() in _code_blocks(guide, "python")
    assert (ROOT / "bench" / "conf" / "optimizer" / "one_plus_one.yaml").read_text() in _code_blocks(guide, "yaml")


def _main_exit(argv, capsys):
    from bench.__main__ import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    out = capsys.readouterr()
    return exit_info.value.code, out.out + out.err


def test_a_missing_data_folder_is_one_message(tmp_path, capsys):
    code, out = _main_exit(["problem=kitti00", "optimizer=random", f"problem.params.data_dir={tmp_path / 'nowhere'}",
                            f"hydra.sweep.dir={tmp_path / 'sweep'}"], capsys)
    assert code == 2 and "nowhere" in out and "Traceback" not in out
    assert not (tmp_path / "sweep").exists()


def test_a_corrupt_data_file_is_one_message_naming_file_and_line(tmp_path, capsys, shared_data):
    data = tmp_path / "data" / "kitti00"
    data.mkdir(parents=True)
    for source in (shared_data / "kitti00").iterdir():
        (data / source.name).symlink_to(source)
    gt = data / "KITTI_00_gt.txt"
    lines = gt.read_text().splitlines()
    gt.unlink()
    lines[41] = "1.0 0.0 not-a-number"
    gt.write_text("\n".join(lines) + "\n")
    code, out = _main_exit(["problem=kitti00", "optimizer=random", f"problem.params.data_dir={tmp_path / 'data'}",
                            f"hydra.sweep.dir={tmp_path / 'sweep'}"], capsys)
    assert code == 2 and "KITTI_00_gt.txt" in out and "42" in out and "Traceback" not in out


def test_help_names_problems_optimisers_and_the_default_sweep(capsys, monkeypatch):
    from bench.__main__ import main

    monkeypatch.setattr(sys, "argv", ["avio-bench", "--help"])  # the console script calls main() with no argv
    main()
    out = capsys.readouterr().out
    import optimizers

    for name in optimizers.available():
        assert name in out
    for problem in ("synthetic", "sphere", "kitti00"):
        assert problem in out
    assert "Default sweep: problem=synthetic, instance=range(0,12), optimizer=psoga,pso,ga,cmaes,tpe,random," in out
    assert "Hydra" not in out.splitlines()[0] and "Powered by Hydra" not in out


def test_hydra_shell_completion_still_works(tmp_path):
    import os

    proc = bench("-sc", "install=bash", cwd=tmp_path)
    assert proc.returncode == 0 and "hydra_bash_completion()" in proc.stdout and "complete -o nospace" in proc.stdout
    line = "avio-bench optimizer=ps"  # what bash hands the script's helper on a tab
    query = subprocess.run([sys.executable, "-m", "bench", "-sc", "query=bash"], cwd=tmp_path, capture_output=True,
                           text=True, timeout=120, env={**os.environ, "COMP_LINE": line, "COMP_POINT": str(len(line))})
    assert query.returncode == 0 and query.stdout.split() == ["optimizer=pso", "optimizer=psoga"]


def test_a_read_only_sweep_folder_is_one_message(tmp_path, monkeypatch):
    from bench.run import preflight

    monkeypatch.setattr(preflight, "_writable", lambda folder: False)  # root ignores chmod, so the probe is replaced
    with pytest.raises(preflight.ConfigError, match=r"hydra.sweep.dir=.*: cannot write in .* \(read-only"):
        preflight.check_sweep_dir(tmp_path / "sweep")


def test_the_probe_sees_a_folder_that_refuses_writes(tmp_path):
    import os

    from bench.run.preflight import _writable

    assert _writable(tmp_path)
    if os.geteuid() != 0:
        tmp_path.chmod(0o555)
        try:
            assert not _writable(tmp_path)
        finally:
            tmp_path.chmod(0o755)


def test_a_single_job_in_hydra_run_mode(tmp_path):
    proc = bench("problem=sphere", "optimizer=random", "budget.evals=32", "hydra.mode=RUN",
                 f"hydra.run.dir={tmp_path / 'one'}", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "job 1/1 sphere/random/i0" in proc.stderr
    assert {"record.json", "job.json", "evals.jsonl"} <= {p.name for p in (tmp_path / "one").iterdir()}


def test_the_harness_runs_blas_on_one_thread_unless_the_environment_says_otherwise():
    code = ("import bench, numpy, scipy.linalg\nfrom threadpoolctl import threadpool_info\n"
            "print(sorted({i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'}))")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}

    def blas_threads(**more) -> str:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**env, **more},
                              cwd=ROOT, timeout=120)
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()

    assert blas_threads() == "[1]"
    if (os.cpu_count() or 1) >= 2:
        assert blas_threads(OPENBLAS_NUM_THREADS="2") == "[2]"  # the user's setting is kept


def test_hydra_takes_the_run_mode_preflight_read_instead_of_composing_the_config_again(tmp_path):
    code = ("from hydra._internal.hydra import Hydra\n"
            "calls = []\n"
            "compose = Hydra.compose_config\n"
            "def counted(self, *args, **kwargs):\n"
            "    calls.append(kwargs.get('validate_sweep_overrides', True))  # False: Hydra.get_mode's\n"
            "    return compose(self, *args, **kwargs)\n"
            "Hydra.compose_config = counted\n"
            "from bench.__main__ import main\n"
            f"main(['problem=sphere', 'optimizer=random', 'instance=0', 'budget.evals=32', 'report=false',\n"
            f"      'hydra.sweep.dir={tmp_path / 's'}'])\n"
            "print('compositions', len(calls), 'for the mode', calls.count(False))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "for the mode 0" in done.stdout and (tmp_path / "s" / "sphere" / "random" / "i0" / "record.json").exists()


def test_the_command_collects_garbage_every_50000_allocations_not_700():
    code = ("import gc, sys\nfrom bench.__main__ import cli\nsys.argv = ['avio-bench', '--version']\n"
            "before = gc.get_threshold()\ncli()\nprint(before[0], gc.get_threshold())")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[-2] == "700 (50000, 20, 100)", done.stdout
