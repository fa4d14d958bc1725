"""The sweep's design, checked before any work (``bench.run.preflight``): the verdict settings the
report will use (``bench.verdict_settings``), and where a problem's truth lies outside its search
bounds, warned about at the start (one line per problem) rather than only in the report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.run.job import identity_of, import_plugins, instance_of
from bench.verdict_settings import VerdictSettings, verdict_settings


def dotted_paths(node, prefix: str = "") -> list[str]:
    """Every key of a config as a dotted path (sections and leaves)."""
    out = []
    if isinstance(node, dict):
        for key, value in node.items():
            path = f"{prefix}.{key}" if prefix else str(key)
            out += [path, *dotted_paths(value, path)]
    return out


def check_design(cfg: dict) -> VerdictSettings:
    """The job's ``instance`` (first: its seed and its problem's data seed follow it) and its verdict
    settings (``check_verdict``; after the plugins, whose problems may carry a ROPE); ConfigError or
    VerdictSettingsError naming the key."""
    instance_of(cfg)
    import_plugins(cfg)
    return check_verdict(cfg)


def check_verdict(cfg: dict) -> VerdictSettings:
    """The job config's ``verdict:`` settings, checked against the keys its record will carry
    (its identity: ``instance``, ``seed``, ``problem.params.data_seed``, ...); VerdictSettingsError."""
    return verdict_settings(cfg.get("verdict"), keys=dotted_paths(identity_of(cfg)))


def truth_outside(problem) -> list[tuple[str, str, float, float, float]]:
    """``(variable, unit, truth, bound, by)`` for each variable whose truth lies outside the search
    bounds (``by`` > 0 above the upper bound, < 0 below the lower one, in the variable's unit);
    empty when the truth is inside or unknown."""
    truth = getattr(problem, "truth", None)
    if truth is None:
        return []
    space = problem.space
    truth = np.asarray(truth, float)
    out = []
    for i, name in enumerate(space.names):
        if truth[i] > space.upper[i]:
            out.append((name, space.units[i], float(truth[i]), float(space.upper[i]), float(truth[i] - space.upper[i])))
        elif truth[i] < space.lower[i]:
            out.append((name, space.units[i], float(truth[i]), float(space.lower[i]), float(truth[i] - space.lower[i])))
    return out


@dataclass
class TruthWarnings:
    """Truth-outside-the-bounds findings of a sweep's problems, gathered per problem name over its
    instances, said in one line per problem (``lines``)."""

    checked: dict[str, set] = field(default_factory=dict)  # problem name -> instances checked
    outside: dict[str, set] = field(default_factory=dict)  # problem name -> instances with the truth outside
    worst: dict[str, dict] = field(default_factory=dict)   # problem name -> {variable: (unit, bound, by)}

    def add(self, name: str, instance, problem) -> None:
        self.checked.setdefault(name, set()).add(instance)
        found = truth_outside(problem)
        if not found:
            return
        self.outside.setdefault(name, set()).add(instance)
        worst = self.worst.setdefault(name, {})
        for variable, unit, _truth, bound, by in found:
            if variable not in worst or abs(by) > abs(worst[variable][2]):
                worst[variable] = (unit, bound, by)

    def lines(self) -> list[str]:
        out = []
        for name in sorted(self.outside):
            parts = [f"{v} {'up to ' if len(self.outside[name]) > 1 else ''}{abs(by):.3g} {unit} "
                     f"{'above' if by > 0 else 'below'} {bound:g}".replace("  ", " ")
                     for v, (unit, bound, by) in self.worst[name].items()]
            n, of = len(self.outside[name]), len(self.checked[name])
            where = (f" on {n} of {of} instances ({', '.join(map(str, sorted(self.outside[name])[:8]))}"
                     f"{', ...' if n > 8 else ''})" if of > 1 else "")
            out.append(f"warning: problem {name}: the truth lies outside the search bounds{where}: "
                       f"{', '.join(parts)}; no optimiser can reach it (widen problem.params.bounds)")
        return out


def seed_sweep_note(overrides: list[str], default_instances) -> str | None:
    """A note when the command line sweeps ``seed`` and leaves ``instance`` to the config's default
    sweep (``default_instances``, e.g. ``range(0,12)``): every seed then runs on every default
    instance, which a user sweeping seeds rarely means (the unit of replication is the instance)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if not default_instances:
        return None
    parsed = OverridesParser.create().parse_overrides([o for o in overrides if not o.lstrip("+~").startswith("hydra")])
    keys = {o.key_or_group: o for o in parsed}
    if "instance" in keys or "seed" not in keys or not keys["seed"].is_sweep_override():
        return None
    return (f"note: seed is swept on each of the default instances (instance={default_instances}); the unit "
            "of replication is the instance: instance='range(k)' pairs optimisers on k instances, with "
            "seed=<k> fixed or left to follow the instance")


__all__ = ["TruthWarnings", "check_design", "check_verdict", "seed_sweep_note", "truth_outside"]
