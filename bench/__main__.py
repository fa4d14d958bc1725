"""``python -m bench [overrides]`` (or ``avio-bench``): validate every job, then run the sweep with Hydra.

Examples::

    python -m bench                                   # the default comparison
    python -m bench optimizer=psoga,pso,cmaes instance='range(10)'
    python -m bench problem=rastrigin budget.evals=500 hydra.sweep.dir=runs/mine   # resumable folder

Exit codes: 0 every job ok; 1 some job failed (the last lines say which); 2 invalid input,
nothing run or written; 130 interrupted (Ctrl-C): the last line is the command that resumes the sweep.
"""

from __future__ import annotations

import gc
import logging
import os
import shlex
import socket
import sys
import uuid
from pathlib import Path

import hydra
from hydra._internal.utils import get_args_parser
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from bench.errors import BenchError
from bench.records import job_name
from bench.run import callbacks, hydra_guard
from bench.run.compose_cache import known_run_mode, skip_sweeper_validation
from bench.run.job import exit_with_the_sweep, plain, run_configured_job
from bench.run.preflight import CONF_DIR, preflight_plan
from bench.run.slurm_check import check_launcher

log = logging.getLogger("bench")

# Part of the default sweep folder name: a timestamp alone lets two sweeps started in the
# same second share a folder. Cached by OmegaConf, and Hydra copies the cache into every job.
OmegaConf.register_new_resolver("bench_unique", lambda: f"{os.getpid()}-{uuid.uuid4().hex[:6]}",
                                use_cache=True, replace=True)
# A job's folder: <problem>/<optimizer>/i<instance> (-seed<seed> when the seed is set apart).
OmegaConf.register_new_resolver("bench_job_name", job_name, replace=True)

@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def _job(cfg: DictConfig) -> float | None:
    exit_with_the_sweep()  # in a launcher's worker: exit when the sweep is killed
    hc = HydraConfig.get()
    job_dir = Path(hc.runtime.output_dir)
    total = os.environ.get("BENCH_SWEEP_JOBS") or "?"
    num = OmegaConf.select(hc, "job.num", default=0) or 0  # missing in hydra.mode=RUN
    label = f"job {num + 1}/{total} {cfg.problem.name}/{cfg.optimizer.name}/{job_name(cfg.instance, cfg.seed)}"
    print(f"{label} -> {job_dir}", file=sys.stderr, flush=True)
    if hc.mode != RunMode.MULTIRUN:  # for the resume hint after a Ctrl-C
        callbacks.LAST_SWEEP["run_dir"] = job_dir
    outcome = run_configured_job(plain(cfg), job_dir, label=label)
    if hc.mode == RunMode.MULTIRUN:  # the sweep's callback counts outcomes
        callbacks.note_outcome(Path(hc.sweep.dir), num, label, outcome)
    else:  # hydra.mode=RUN: one job in this process, no sweep callback
        callbacks.LAST_SWEEP.update(n_jobs=1, n_failed=int(outcome.get("status") != "ok"))
    return outcome.get("best_f") if outcome.get("status") == "ok" else None


def help_text() -> str:
    """``--help``: the problems, optimisers and default sweep (read from the registries and config.yaml)."""
    import optimizers
    from bench import problems

    primary = OmegaConf.load(CONF_DIR / "config.yaml")
    sweep = OmegaConf.to_container(primary.hydra.sweeper.params)
    defaults = {k: v for d in OmegaConf.to_container(primary.defaults) if isinstance(d, dict) for k, v in d.items()}
    problem_yamls = sorted(p.stem for p in (CONF_DIR / "problem").glob("*.yaml"))
    return "\n".join([
        "avio-bench (python -m bench): calibrate a visual-inertial odometry with black-box optimisers.",
        "",
        "Usage: avio-bench [key=value ...]     a Hydra app in MULTIRUN mode: a,b,c and range(n) sweep",
        "",
        f"Problems   (problem=...):   {', '.join(problem_yamls)}",
        f"Optimisers (optimizer=...): {', '.join(optimizers.available())}",
        f"Registered problem classes: {', '.join(problems.available())}",
        "",
        f"Default sweep: problem={defaults.get('problem')}, "
        + ", ".join(f"{k}={v}" for k, v in sweep.items())
        + f", budget.evals={primary.budget.evals}, budget.seconds={primary.budget.seconds}",
        "",
        "Examples:",
        "  avio-bench optimizer=psoga,pso,cmaes instance='range(10)' budget.evals=500",
        "  avio-bench problem=sphere optimizer=random hydra.sweep.dir=runs/mine   # a fixed folder resumes",
        "  avio-bench hydra/launcher=joblib hydra.launcher.n_jobs=4",
        "",
        "Every job is validated before any work (exit 2 with one message); a job that fails is recorded",
        "and the sweep goes on (exit 1 at the end). Records: <sweep>/<problem>/<optimizer>/i<instance>/.",
        "",
        "More: --cfg job (the composed config), --hydra-help (Hydra's flags),",
        "      --shell-completion install=bash (tab completion), README.md.",
    ])


def resume_hint(argv: list[str], program: str = "") -> str:
    """The line printed after a Ctrl-C: the folder, and the command that resumes it.

    The default sweep folder is named by the time it started, so the same command line would start a
    new one: the hint adds ``hydra.sweep.dir=`` (``hydra.run.dir=`` in ``hydra.mode=RUN``) unless the
    command line already fixes it.
    """
    single = "run_dir" in callbacks.LAST_SWEEP
    folder = callbacks.LAST_SWEEP.get("run_dir" if single else "sweep_dir")
    if folder is None:
        return "Interrupted before the sweep started: nothing was run or written."
    key = "hydra.run.dir" if single else "hydra.sweep.dir"
    fixed = any(a.lstrip("+").startswith(f"{key}=") for a in argv)
    typed = ["avio-bench"] if Path(program).name == "avio-bench" else ["python", "-m", "bench"]
    command = [*typed, *argv, *([] if fixed else [f"{key}={folder}"])]
    what = "job" if single else "sweep"
    return f"Interrupted: the {what} in {folder} resumes with: {shlex.join(command)}"


def main(argv: list[str] | None = None) -> None:
    """The console entry point (``avio-bench``); ``argv`` defaults to ``sys.argv[1:]``."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if any(a in ("--help", "-h") for a in argv):
        print(help_text())
        return
    if "--version" in argv:  # ours, before Hydra's (which would print Hydra's version)
        from bench import version

        print(f"avio-bench {version()}")
        return
    get_args_parser().parse_args(argv)  # a flag Hydra does not know: its usage on stderr, exit 2, before any work
    callbacks.LAST_SWEEP.clear()
    try:
        code, plan = preflight_plan(argv)
    except KeyboardInterrupt:
        print(resume_hint(argv, sys.argv[0] if sys.argv else ""), file=sys.stderr, flush=True)
        raise SystemExit(130) from None
    if code:
        raise SystemExit(code)
    if plan is not None:  # a cluster launcher's settings, asked of the cluster before anything is submitted
        try:
            check_launcher(argv, CONF_DIR, plan.n_jobs)
        except BenchError as err:
            print(f"error: {err}", file=sys.stderr)
            raise SystemExit(2) from None
    if plan is not None and plan.sweep_dir is not None:  # for bench.status: the jobs not started yet
        callbacks.LAST_SWEEP["planned"] = [str(d.relative_to(plan.sweep_dir)) for d in plan.job_dirs
                                           if d.is_relative_to(plan.sweep_dir)]
    if plan is not None:
        skip_sweeper_validation()  # preflight composed every job: Hydra's sweeper need not again (~0.1 s a job)
        if plan.mode is not None:
            known_run_mode(plan.mode)  # nor Hydra's own composition that only reads hydra.mode
    os.environ["BENCH_SWEEP_PID"] = str(os.getpid())  # launchers' local workers exit when it is gone
    os.environ["BENCH_SWEEP_HOST"] = socket.gethostname()
    os.environ["BENCH_SWEEP_JOBS"] = str(plan.n_jobs) if plan is not None else ""
    hydra_guard.install()  # Hydra's own set-up of a job failing fails that job, not the sweep
    saved = sys.argv
    sys.argv = [saved[0] if saved else "avio-bench", *argv]  # Hydra parses sys.argv
    try:
        _job()
    except KeyboardInterrupt:  # Ctrl-C: what was logged stays; one line says how to go on from it
        print(resume_hint(argv, saved[0] if saved else ""), file=sys.stderr, flush=True)
        raise SystemExit(130) from None
    finally:
        sys.argv = saved
    if callbacks.LAST_SWEEP.get("n_failed"):
        raise SystemExit(1)


def cli() -> None:
    """``main()`` as a command (``python -m bench``, ``avio-bench``): at the end the objects of the run are
    frozen out of the garbage collector, so the interpreter's exit does not walk them one last time
    (with the freeze after the imports, 4.41-4.58 -> 4.13-4.23 s for a 500-evaluation job). Not in ``main``,
    which tests call in their own process."""
    gc.freeze()  # the objects of the imports so far (Hydra, OmegaConf): no collection during the run walks them
    # A collection every 50,000 allocations, not 700: the imports and compositions still to come allocate
    # objects that live as long as the process (a default job 1.016x, 7 pairs: benchmarks/README.md).
    gc.set_threshold(50_000, 20, 100)
    try:
        main()
    finally:
        gc.freeze()


if __name__ == "__main__":
    cli()
