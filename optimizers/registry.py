"""Optimiser registry: ``@register("name")`` on the plugin class, looked up by the yaml's name.

Plugins import their libraries lazily (inside ``__init__``) so that discovering all of them
stays cheap.
"""

from __future__ import annotations

import importlib
import pkgutil

_REGISTRY: dict[str, type] = {}
_NOT_PLUGINS = {"base", "registry"}


def register(name: str):
    """Class decorator that registers an optimiser under ``name`` (the ``name`` in its yaml)."""

    def decorate(cls: type) -> type:
        if name in _REGISTRY and _REGISTRY[name] is not cls:
            raise ValueError(f"optimiser name {name!r} registered twice: {_REGISTRY[name]} and {cls}")
        _REGISTRY[name] = cls
        cls.registered_name = name
        return cls

    return decorate


def _discover() -> None:
    import optimizers

    for info in pkgutil.iter_modules(optimizers.__path__):
        if info.name not in _NOT_PLUGINS and not info.name.startswith("_"):
            importlib.import_module(f"optimizers.{info.name}")


def available() -> list[str]:
    """Sorted names of every registered optimiser."""
    _discover()
    return sorted(_REGISTRY)


def get(name: str) -> type:
    """The optimiser class registered as ``name``; KeyError lists the valid names."""
    _discover()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown optimizer {name!r}; valid names: {', '.join(sorted(_REGISTRY))}") from None
