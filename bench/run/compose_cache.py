"""Compose many job configs of one sweep fast: Hydra's full composition once per *kind* of job.

Hydra's ``compose`` costs ~0.1 s a job (a defaults tree, yaml loads, merges), ~17 minutes for 10,000 jobs.
The jobs of a sweep mostly differ in plain values (``seed=3``, ``budget.evals=500``), which Hydra applies
last, with ``OmegaConf.update``, on the config the groups made. So jobs whose overrides are the same
but for such values share one composition: the first is composed by Hydra, the others are that config
with their values set as Hydra sets them (``OmegaConf.update(cfg, key, value, merge=True)``), with
``hydra.overrides.task`` and ``hydra.job.override_dirname`` rewritten. The second job of each kind is
also composed in full and compared; any difference turns the shortcut off for that kind (every job
of it then composed by Hydra).
"""

from __future__ import annotations

from pathlib import Path

from hydra import compose
from hydra._internal.config_loader_impl import get_overrides_dirname
from hydra.core.global_hydra import GlobalHydra
from hydra.core.object_type import ObjectType
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from omegaconf import DictConfig, OmegaConf, open_dict

_PRIMITIVES = (int, float, str, bool, type(None))


class JobComposer:
    """``composer(job_overrides) -> hcfg``: the job's config with its hydra node, as ``compose`` returns it.

    ``extra`` are the command line's hydra overrides (the same for every job). Use inside
    ``initialize_config_dir``; the returned config may be changed by the next call (read it first).
    """

    def __init__(self, extra: list[str]) -> None:
        self.extra = list(extra)
        self.parser = OverridesParser.create()
        self._groups: dict[str, bool] = {}
        self._kinds: dict[tuple, dict] = {}
        self._parsed: dict[str, Override] = {}  # an override string parsed once (the parser costs ~1 ms)
        self.full = 0  # compositions by Hydra (for the benchmark)

    def _is_group(self, key: str) -> bool:
        if key not in self._groups:
            loader = GlobalHydra.instance().config_loader()
            self._groups[key] = bool(loader.get_group_options(key, ObjectType.CONFIG, config_name="config"))
        return self._groups[key]

    def _plain(self, override: Override) -> bool:
        """A value Hydra sets with ``OmegaConf.update`` after the groups are composed."""
        return (override.type == OverrideType.CHANGE and not override.is_hydra_override()
                and override.package is None and not override.is_sweep_override()
                and "/" not in override.key_or_group and not self._is_group(override.key_or_group)
                and isinstance(override.value(), _PRIMITIVES))

    def _compose(self, overrides: list[str]) -> DictConfig:
        self.full += 1
        return compose("config", overrides=overrides + self.extra, return_hydra_config=True)

    def __call__(self, overrides: list[str]) -> DictConfig:
        for line in overrides:
            if line not in self._parsed:
                self._parsed[line] = self.parser.parse_overrides([line])[0]
        parsed = [self._parsed[line] for line in overrides]
        plain = [self._plain(o) for o in parsed]
        kind = tuple(o.key_or_group if p else o.input_line for o, p in zip(parsed, plain))
        entry = self._kinds.get(kind)
        if entry is None:
            self._kinds[kind] = {"cfg": self._compose(overrides), "checked": False, "ok": True}
            return self._kinds[kind]["cfg"]
        if not entry["ok"]:
            return self._compose(overrides)
        cfg = _patch(entry["cfg"], parsed, plain)
        if not entry["checked"]:
            entry["checked"] = True
            truth = self._compose(overrides)
            if _fingerprint(truth) != _fingerprint(cfg):
                entry["ok"] = False
                return truth
        return cfg


def _patch(cfg: DictConfig, parsed: list[Override], plain: list[bool]) -> DictConfig:
    """Set the job's plain values on ``cfg`` as Hydra does, and its recorded overrides."""
    app = [o for o in parsed if not o.is_hydra_override()]
    with open_dict(cfg):
        for override, is_plain in zip(parsed, plain):
            if is_plain:
                OmegaConf.update(cfg, override.key_or_group, override.value(), merge=True)
        task = cfg.hydra.overrides.task  # as Hydra lists them: the app's, in order
        lines = [o.input_line for o in app]
        if len(task) != len(lines):
            cfg.hydra.overrides.task = lines
        else:
            for i, line in enumerate(lines):
                if task[i] != line:
                    task[i] = line
        dirname = cfg.hydra.job.config.override_dirname
        cfg.hydra.job.override_dirname = get_overrides_dirname(
            overrides=app, kv_sep=dirname.kv_sep, item_sep=dirname.item_sep, exclude_keys=dirname.exclude_keys)
    return cfg


def _fingerprint(cfg: DictConfig) -> str:
    """The whole config (hydra node included), resolved where it can be, as a string."""
    hydra = OmegaConf.to_container(cfg.hydra, resolve=False)
    job = OmegaConf.to_container(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True)
    return repr((job, hydra))


def job_part(cfg: DictConfig) -> dict:
    """The job's own config (Hydra's node left out), resolved, as plain data (without copying the config)."""
    part = {}
    for key in cfg:
        if key == "hydra":
            continue
        node = cfg._get_node(key)
        part[key] = OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else cfg[key]
    return part


def top_level_keys(conf_dir: Path, search: list[str]) -> set[str]:
    """The composed config's top-level keys (``hydra`` aside). Without a ``hydra.searchpath`` override
    they are read from ``conf_dir``/config.yaml, its own keys and its defaults' groups (~1 ms, where a composition
    costs ~0.17 s of every ``python -m bench``; a test keeps the two equal); with one, composed."""
    if search:
        return set(compose("config", overrides=search).keys())
    node = OmegaConf.to_container(OmegaConf.load(conf_dir / "config.yaml"))
    groups = {next(iter(entry)).removeprefix("override ").split("@")[0].split("/")[0]
              for entry in node.pop("defaults", []) if isinstance(entry, dict)}
    return (set(node) | groups) - {"hydra"}


def skip_sweeper_validation() -> None:
    """Let Hydra's sweeper launch without composing every job first (``Sweeper.validate_batch_is_legal``).

    The sweeper composes each job once more before the launcher composes it again where it runs: ~0.1 s a
    job in the sweep's own process, 17 minutes of a 10,000-job submission. ``python -m bench`` calls this only
    after preflight has composed and checked every job of the same command line, so a job that cannot be
    composed has already stopped the sweep with exit code 2. For this process only; idempotent.
    """
    from hydra.plugins.sweeper import Sweeper

    Sweeper.validate_batch_is_legal = _validated_by_preflight


def known_run_mode(mode) -> None:
    """Let Hydra take its run mode (``hydra.mode``) as preflight read it, instead of composing the whole config
    once more to read it (``Hydra.get_mode``: 0.06 s of a 4-s job). ``python -m bench`` calls this only with
    the mode of a config preflight composed from the same command line. For this process only."""
    from hydra._internal.hydra import Hydra

    def get_mode(self, config_name, overrides):
        return mode

    Hydra.get_mode = get_mode


def _validated_by_preflight(self, batch) -> None:
    """Every job of ``batch`` was composed by ``bench.run.preflight`` (see ``skip_sweeper_validation``)."""


class SweepConfigCache:
    """``load_sweep_config`` of Hydra's config loader, with the shortcut of ``JobComposer``, for a packed task.

    The jobs of one array task (``hydra/launcher=bench_slurm`` with ``pack`` > 1) differ mostly in plain
    values; each job's config is a copy of the first of its kind with its values set as Hydra sets them,
    the second of each kind checked against Hydra's full composition (any difference: full composition).
    """

    def __init__(self, loader) -> None:
        self.loader = loader
        self.original = loader.load_sweep_config
        self.parser = OverridesParser.create()
        self._parsed: dict[str, Override] = {}
        self._groups: dict[str, bool] = {}
        self._kinds: dict[tuple, dict] = {}

    def _is_group(self, key: str) -> bool:
        if key not in self._groups:
            self._groups[key] = bool(self.loader.get_group_options(key, ObjectType.CONFIG))
        return self._groups[key]

    def __call__(self, master_config: DictConfig, sweep_overrides: list[str]) -> DictConfig:
        import copy

        for line in sweep_overrides:
            if line not in self._parsed:
                self._parsed[line] = self.parser.parse_overrides([line])[0]
        parsed = [self._parsed[line] for line in sweep_overrides]
        plain = [JobComposer._plain(self, o) for o in parsed]  # type: ignore[arg-type]
        kind = tuple(o.key_or_group if p else o.input_line for o, p in zip(parsed, plain))
        entry = self._kinds.get(kind)
        if entry is None or not entry["ok"]:
            cfg = self.original(master_config, sweep_overrides)
            if entry is None:
                self._kinds[kind] = {"cfg": copy.deepcopy(cfg), "checked": False, "ok": True}
            return cfg
        cfg = _patch(copy.deepcopy(entry["cfg"]), parsed, plain)
        if not entry["checked"]:
            entry["checked"] = True
            truth = self.original(master_config, sweep_overrides)
            if _fingerprint(truth) != _fingerprint(cfg):
                entry["ok"] = False
                return truth
        return cfg
