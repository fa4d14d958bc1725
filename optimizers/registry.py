"""Registries of plugins by name: ``@register("name")`` on the plugin class, looked up by the name
its yaml uses. :class:`Registry` is the one implementation; optimisers use the module-level
functions below, ``bench.problems`` a registry of its own.

Plugins import their libraries lazily (inside ``__init__``) so that discovering all of them
stays cheap.
"""

from __future__ import annotations

import importlib
import pkgutil


class Registry:
    """Classes registered by name; every module of ``package`` (but ``skip`` and private ones) is
    imported on first lookup, so a plugin registers itself by being in the package."""

    def __init__(self, kind: str, package: str, skip: frozenset[str] = frozenset()):
        self.kind, self.package, self.skip = kind, package, skip
        self._classes: dict[str, type] = {}

    def register(self, name: str):
        """Class decorator that registers ``cls`` under ``name`` (the ``name`` in its yaml).

        The name becomes a folder of every job's path (``<sweep>/<problem>/<optimizer>/seed<k>``), so
        it must be one plain path component: ValueError for an empty name, or one with ``/``, ``\\``,
        ``..``, a NUL byte or a leading ``.`` (which could put a job folder outside the sweep, or hide it).
        """
        check_name(self.kind, name)

        def decorate(cls: type) -> type:
            if name in self._classes and self._classes[name] is not cls:
                raise ValueError(f"{self.kind} name {name!r} registered twice: {self._classes[name]} and {cls}")
            self._classes[name] = cls
            cls.registered_name = name
            return cls

        return decorate

    def _discover(self) -> None:
        package = importlib.import_module(self.package)
        for info in pkgutil.iter_modules(package.__path__):
            if info.name not in self.skip and not info.name.startswith("_"):
                importlib.import_module(f"{self.package}.{info.name}")

    def available(self) -> list[str]:
        """Sorted names of every registered class."""
        self._discover()
        return sorted(self._classes)

    def get(self, name: str) -> type:
        """The class registered as ``name``; KeyError lists the valid names."""
        self._discover()
        try:
            return self._classes[name]
        except KeyError:
            raise KeyError(f"unknown {self.kind} {name!r}; valid names: {', '.join(sorted(self._classes))}") from None


def check_name(kind: str, name) -> None:
    """ValueError unless ``name`` is a non-empty string usable as one folder name (see ``Registry.register``)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"{kind} name {name!r}: must be a non-empty string (it names the job folders)")
    bad = [why for why, hit in (("a '/'", "/" in name), ("a '\\'", "\\" in name), ("'..'", ".." in name),
                                ("a NUL byte", "\0" in name), ("a leading '.'", name.startswith(".")))
           if hit]
    if bad:
        raise ValueError(f"{kind} name {name!r} holds {' and '.join(bad)}: it names a job folder "
                         "(<sweep>/<problem>/<optimizer>/seed<k>), so it must be one plain folder name")


OPTIMIZERS = Registry("optimizer", "optimizers", skip=frozenset({"base", "registry"}))
register, available, get = OPTIMIZERS.register, OPTIMIZERS.available, OPTIMIZERS.get
