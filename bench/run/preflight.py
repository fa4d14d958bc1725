"""Validate every job of a sweep before any work starts, and before Hydra writes anything.

Hydra composes and launches jobs one by one, so a typo in the fifth optimiser name, a budget of 0 or a missing
data file would surface only after the first jobs ran. Here the command line is expanded exactly as Hydra's
basic sweeper expands it, each job config is composed with Hydra's compose API, and each is checked: the
instance (an integer >= 0), the report's verdict settings (``bench.verdict_settings``), registered names,
plugins, budget, seed, progress interval, the filter's threads (``threads``, NUMBA_NUM_THREADS), no NaN, the
problem's own cheap checks (``Problem.preflight``: its search space, its data files), the problem itself
(built once per distinct problem config, as the first job would build it: a serial sweep's jobs then reuse
it), the optimiser built on the job's space with its hyperparameters (and asked once), the sweep folder (a
writable folder), and every job folder that already exists (it must hold this very job — same resolved config
—, not be in use by another process, and hold no symbolic link in place of its files). The first problem found
is one clear message and exit code 2; nothing has been written. A problem whose truth lies outside its search
bounds is warned about, one line per problem, before the sweep starts (``bench.run.design_checks``).
"""

from __future__ import annotations

import difflib
import json
import math
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.global_hydra import GlobalHydra
from hydra.core.object_type import ObjectType
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

import optimizers
from avio.errors import AvioError
from bench import problems
from bench.errors import BenchError
from bench.records import (
    EVAL_LOG,
    JOB_FILE,
    LOCK_FILE,
    RECORD,
    RecordError,
    lock_holder,
    read_job_file,
    read_record,
    refuse_symlink,
)
from bench.run.compose_cache import JobComposer, job_part, top_level_keys
from bench.run.design_checks import TruthWarnings, check_design, dotted_paths, seed_sweep_note
from bench.run.identity import config_hash, identity_differences
from bench.run.job import ConfigError, budget_of, check_presentation, identity_of, import_plugins, instance_of, seed_of
from bench.run.log_checks import linked_file
from bench.space import Space

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
_HYDRA_FLAGS_WITHOUT_JOBS = {"--help", "-h", "--hydra-help", "--version", "--info", "-i", "--cfg", "-c",
                             "--shell-completion", "-sc", "--resolve"}


@dataclass
class SweepPlan:
    """What preflight found: the number of distinct jobs, the sweep folder (when resolved), Hydra's ``hydra.mode``."""

    n_jobs: int = 0
    sweep_dir: Path | None = None
    job_dirs: list[Path] = field(default_factory=list)
    mode: object = None


def expand_jobs(argv: list[str]) -> list[list[str]]:
    """The override lists of every job the sweep will run (config sweeper params + command line)."""
    overrides = [a for a in argv if not a.startswith("-")]
    # hydra.searchpath decides which configs exist; Hydra's other settings do not change jobs
    app_overrides = [o for o in overrides
                     if not o.lstrip("+~").startswith("hydra") or o.startswith("hydra.searchpath")]
    parser = OverridesParser.create()
    # The sweeper params of the primary config, read as data: composing it would need a
    # valid default for every swept group first.
    primary = OmegaConf.load(CONF_DIR / "config.yaml")
    if "hydra.mode=RUN" in overrides:  # one job: Hydra ignores the sweeper's params
        return [app_overrides]
    params = OmegaConf.select(primary, "hydra.sweeper.params") or {}
    sweep_params = [f"{k}={v}" for k, v in params.items()]
    parsed = parser.parse_overrides(sweep_params + app_overrides)
    return BasicSweeper.split_arguments(parsed, None)[0]


def _default_instances() -> str | None:
    """The config's default ``instance`` sweep (hydra.sweeper.params.instance), as written."""
    return OmegaConf.select(OmegaConf.load(CONF_DIR / "config.yaml"), "hydra.sweeper.params.instance")


def _nearest_key(key: str, paths: list[str]) -> str | None:
    """The valid key nearest to ``key``, comparing it with whole paths and with their last part
    (``evals`` -> ``budget.evals``)."""
    def score(path: str) -> float:
        return max(difflib.SequenceMatcher(None, key, candidate).ratio()
                   for candidate in (path, path.rsplit(".", 1)[-1]))
    best = max(paths, key=score, default=None)
    return best if best is not None and score(best) >= 0.4 else None


def check_keys(argv: list[str]) -> None:
    """Refuse an override of a top-level key the config does not have, before any work.

    ``+objective=foo`` (what Hydra suggests after a typo such as ``objective=foo``) would add a key
    that nothing reads and run the default sweep; this names the key and the nearest valid one.
    Hydra's own keys (``hydra.*``, ``+hydra/...``), config groups (``+group=option``, also from
    ``hydra.searchpath``) and keys under a known section (``+optimizer.params.x=1``, checked later
    with the job) pass. Must run inside ``initialize_config_dir``.
    """
    overrides = [a for a in argv if not a.startswith("-")]
    search = [o for o in overrides if o.lstrip("+~").startswith("hydra.searchpath")]
    parsed = OverridesParser.create().parse_overrides([o for o in overrides if not o.lstrip("+~").startswith("hydra")])
    if not parsed:
        return
    known = top_level_keys(CONF_DIR, search)
    loader = GlobalHydra.instance().config_loader()
    for override in parsed:
        key = override.key_or_group
        top = key.split("/")[0].split(".")[0]
        if override.is_delete() or top in known:
            continue
        if loader.get_group_options(key, ObjectType.CONFIG, config_name="config", overrides=search):
            continue  # +group=option: a config group (Hydra checks the option)
        paths = dotted_paths(OmegaConf.to_container(compose("config", overrides=search)))
        for group in ("problem", "optimizer"):
            for yaml in sorted((CONF_DIR / group).glob("*.yaml")):
                found = dotted_paths(OmegaConf.to_container(OmegaConf.load(yaml)), group)
                paths += [p for p in found if p not in paths]
        nearest = _nearest_key(key, paths)
        hint = f"did you mean {nearest}? " if nearest else ""
        raise ConfigError(f"{override.input_line}: the config has no key {top!r}, so nothing would read it; "
                          f"{hint}Top-level keys: {', '.join(sorted(known))}")


_BUILT: set[str] = set()  # problem configs announced (build_problem caches the problems themselves)


def _built_problem(cfg: dict):
    """The job's problem, built as a job builds it (``bench.problems.build_problem``, cached per process,
    so a serial sweep's jobs reuse it); a problem that cannot be built is a ConfigError. Said once per
    problem name (its instances are built too, silently)."""
    from bench.problems.base import build_problem

    name = cfg["problem"]["name"]
    if name not in _BUILT:
        _BUILT.add(name)
        print(f"Checking: building problem {name} (each instance) to check the optimisers on its space ...",
              file=sys.stderr, flush=True)
    try:
        return build_problem(cfg)
    except (BenchError, AvioError, OSError, TypeError, KeyError) as err:
        raise ConfigError(f"problem={name}: {err}") from None


def check_optimizer(cfg: dict, space: Space) -> None:
    """Build the job's optimiser on ``space`` exactly as a job does, and ask it once."""
    name = cfg["optimizer"]["name"]
    params = cfg["optimizer"].get("params") or {}
    if not isinstance(params, dict):
        raise ConfigError(f"optimizer.params must be a section of hyperparameters, got {params!r}")
    cls = optimizers.get(name)
    try:
        opt = cls(space.lower, space.upper, seed=int(cfg["seed"]), x0=space.reference, **params)
    except optimizers.OptimizerError as err:
        raise ConfigError(f"optimizer.params: {err}") from None
    except TypeError as err:
        raise ConfigError(f"optimizer={name}: cannot be built as {cls.__name__}(lower, upper, seed=, x0=, "
                          f"**params) with params {sorted(params)}: {err}") from None
    try:  # an OptimizerError is bad input; any other error is the plugin's bug and keeps its traceback
        X = opt.ask()
    except optimizers.OptimizerError as err:
        raise ConfigError(f"optimizer={name} with params {params}: its first ask() fails: "
                          f"{type(err).__name__}: {err}") from None
    finally:
        close = getattr(opt, "close", None)
        if callable(close):
            close()
    space.check(X)


def check_job(cfg: dict, truths: TruthWarnings | None = None) -> None:
    """Raise ConfigError if one composed job config is invalid; note in ``truths`` whether its
    problem's truth lies outside the search bounds (when built). Presentation settings are checked
    by the caller for every job (``check_presentation``): not in the identity configs are deduped by."""
    _check_finite(cfg, "")
    import_plugins(cfg)
    name = cfg["optimizer"].get("name")
    if name not in optimizers.available():
        raise ConfigError(f"optimizer={name!r} is not registered; valid names: {', '.join(optimizers.available())}")
    pname = cfg["problem"].get("name")
    if pname not in problems.available():
        raise ConfigError(f"problem={pname!r} is not registered; valid names: {', '.join(problems.available())}")
    budget_of(cfg)
    seed_of(cfg)
    factory = problems.get(pname)
    checker = getattr(factory, "preflight", None)
    checked = None
    if checker is not None:
        try:
            checked = checker(**(cfg["problem"].get("params") or {}))
        except (BenchError, AvioError, OSError, TypeError) as err:
            raise ConfigError(f"problem={pname}: {err}") from None
    if isinstance(checked, Space):
        check_optimizer(cfg, checked)
        return
    # the hyperparameters first on the paper's box (cheap, and most mistakes show there), then on
    # the job's own space, which needs the problem built (its data, its bounds, fixed variables)
    from bench.problems.analytic import paper_box_space

    check_optimizer(cfg, paper_box_space())
    problem = _built_problem(cfg)
    check_optimizer(cfg, problem.space)
    if truths is not None:
        truths.add(pname, cfg.get("instance"), problem)


def _check_finite(node, path: str) -> None:
    if isinstance(node, dict):
        for key, value in node.items():
            _check_finite(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            _check_finite(value, f"{path}[{i}]")
    elif isinstance(node, float) and not math.isfinite(node):
        raise ConfigError(f"{path} is {node}: numbers in the config must be finite")


def _writable(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (a real probe: os.access says yes to root on read-only mounts)."""
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".bench-probe-"):
            return True
    except OSError:
        return False


def check_sweep_dir(sweep_dir: Path) -> None:
    """The sweep folder must be a folder (or not exist yet) in a place that can be written."""
    if sweep_dir.exists() and not sweep_dir.is_dir():
        raise ConfigError(f"hydra.sweep.dir={sweep_dir} is a file, not a folder")
    existing = sweep_dir
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise ConfigError(f"hydra.sweep.dir={sweep_dir}: {existing} is a file, not a folder")
    if not _writable(existing):
        raise ConfigError(f"hydra.sweep.dir={sweep_dir}: cannot write in {existing} (read-only or no permission)")
    holder = lock_holder(sweep_dir)
    if holder:
        raise ConfigError(f"hydra.sweep.dir={sweep_dir} is in use by another sweep ({holder}); two sweeps in one "
                          "folder would run the same jobs twice: wait for it to end or choose another folder")


def check_job_dir(job_dir: Path, cfg: dict) -> None:
    """An existing job folder must hold this job (same resolved config) and be free."""
    if not job_dir.exists():
        return
    if not job_dir.is_dir():
        raise ConfigError(f"job folder {job_dir} is a file, not a folder")
    for name in (EVAL_LOG, RECORD, JOB_FILE, LOCK_FILE):
        try:
            refuse_symlink(job_dir / name)
        except RecordError as err:
            raise ConfigError(str(err)) from None
    linked = linked_file(job_dir)  # Hydra's .hydra/ files and job log too
    if linked:
        raise ConfigError(linked)
    holder = lock_holder(job_dir)
    if holder:
        raise ConfigError(f"job folder {job_dir} is in use by {holder}; wait for it to end or choose another "
                          "hydra.sweep.dir")
    identity = identity_of(cfg)
    try:
        header = read_job_file(job_dir)
        record = read_record(job_dir)
    except RecordError:
        return  # a corrupt file fails that job alone, with its message, when it runs
    old = (header or {}).get("identity") if header else (record or {}).get("identity")
    old_hash = (header or {}).get("config_hash") if header else (record or {}).get("config_hash")
    log_size = (job_dir / EVAL_LOG).stat().st_size if (job_dir / EVAL_LOG).exists() else 0
    if old_hash is None:
        if log_size or (record is not None and record.get("status") == "ok"):
            raise ConfigError(f"job folder {job_dir} holds results without a job identity (an older version "
                              f"wrote them), so they cannot be checked against this config; choose another "
                              "hydra.sweep.dir or move them away")
        return
    if old_hash != config_hash(identity) and (log_size or (record is not None and record.get("status") == "ok")):
        diff = identity_differences(old or {}, identity) or "another config"
        raise ConfigError(f"job folder {job_dir} holds a job with other settings ({diff}); resuming or skipping it "
                          "would mix results: restore the settings or choose another hydra.sweep.dir")


def _hydra_overrides(argv: list[str]) -> list[str]:
    return [a for a in argv if not a.startswith("-") and a.lstrip("+~").startswith("hydra")
            and "=" in a and not a.startswith(("hydra/", "hydra.launcher", "hydra.sweeper", "hydra.callbacks"))]


def _job_dir(hcfg) -> tuple[Path | None, Path | None]:
    """(sweep dir, job dir) as Hydra will resolve them from a config composed with its hydra node;
    None where they cannot be resolved here (a subdir template that uses Hydra's runtime values)."""
    try:
        sweep = OmegaConf.select(hcfg, "hydra.sweep.dir", throw_on_resolution_failure=True)
    except (OmegaConfBaseException, ValueError):
        return None, None
    if sweep is None:
        return None, None
    try:
        sub = OmegaConf.select(hcfg, "hydra.sweep.subdir", throw_on_resolution_failure=True)
    except (OmegaConfBaseException, ValueError):
        return Path(str(sweep)), None
    return Path(str(sweep)), (Path(str(sweep)) / str(sub) if sub is not None else None)


def _job_part(hcfg) -> dict:
    """The job's own config (Hydra's node left out), resolved, as plain data."""
    return OmegaConf.to_container(OmegaConf.masked_copy(hcfg, [k for k in hcfg if k != "hydra"]), resolve=True)


def plan(argv: list[str]) -> SweepPlan:
    """Validate every job the command line would run; raise ConfigError/HydraException at the first problem."""
    GlobalHydra.instance().clear()
    result = SweepPlan()
    seen: set[str] = set()
    hydra_overrides = _hydra_overrides(argv)
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="preflight"):
            check_keys(argv)
            jobs = expand_jobs(argv)
            note = seed_sweep_note([a for a in argv if not a.startswith("-")], _default_instances())
            if note:
                print(note, file=sys.stderr, flush=True)
            if len(jobs) > 4:
                print(f"Checking {len(jobs)} jobs before any work ...", file=sys.stderr, flush=True)
            truths = TruthWarnings()
            composer = JobComposer(hydra_overrides)  # Hydra's full composition once per kind of job
            for job_overrides in jobs:
                hcfg = composer(job_overrides)
                result.mode = OmegaConf.select(hcfg, "hydra.mode")  # every job's: only hydra overrides set it
                cfg = job_part(hcfg)
                instance_of(cfg), seed_of(cfg)  # each configuration checked once below
                check_presentation(cfg)  # every job: these keys are not in the identity; first: NUMBA_NUM_THREADS
                key = json.dumps({k: v for k, v in identity_of(cfg).items() if k != "seed"}, sort_keys=True,
                                 default=str)
                if key not in seen:
                    seen.add(key)
                    check_design(cfg)  # the instance and the report's settings, before the problem is built
                    check_job(cfg, truths)
                result.n_jobs += 1
                sweep_dir, job_dir = _job_dir(hcfg)
                if sweep_dir is not None and result.sweep_dir is None:
                    result.sweep_dir = sweep_dir
                    check_sweep_dir(sweep_dir)
                if job_dir is not None:
                    check_job_dir(job_dir, cfg)
                    result.job_dirs.append(job_dir)
    finally:
        GlobalHydra.instance().clear()
    for line in truths.lines():
        print(line, file=sys.stderr, flush=True)
    return result


def preflight(argv: list[str]) -> int:
    """Validate every job the command line would run; 0 if all are valid, else print why and return 2."""
    code, _ = preflight_plan(argv)
    return code


def preflight_plan(argv: list[str]) -> tuple[int, SweepPlan | None]:
    """``(exit code, plan)``: 0 and the plan when every job is valid; 2 and None after printing the reason."""
    if any(a.split("=")[0] in _HYDRA_FLAGS_WITHOUT_JOBS for a in argv):
        return 0, None
    try:
        return 0, plan(argv)
    except (BenchError, AvioError, optimizers.OptimizerError) as err:  # ConfigError and the like; not a bug
        print(f"error: {err}", file=sys.stderr)
    except HydraException as err:
        print(f"error: {str(err).split(chr(10) + 'Config search path')[0].strip()}", file=sys.stderr)
    except OmegaConfBaseException as err:
        print(f"error: {str(err).splitlines()[0]}", file=sys.stderr)
    return 2, None


def compose_job(overrides: list[str]) -> dict:
    """One job's config as plain data, composed from ``conf/`` with ``overrides`` (for scripts)."""
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(str(CONF_DIR), version_base="1.3", job_name="script"):
            return OmegaConf.to_container(compose("config", overrides=overrides), resolve=True)
    finally:
        GlobalHydra.instance().clear()


__all__ = ["SweepPlan", "check_job", "check_keys", "compose_job", "expand_jobs", "plan", "preflight", "preflight_plan"]
