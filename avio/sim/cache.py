"""Simulated drives cached on disk, so that a job loads a drive it has made before.

A drive is a pure function of its ``SimConfig``, its seeds, the true calibration it is given and the
simulator's code (``simulate``'s docstring). Simulating the default problem's two drives costs
~0.4 s and the imports of scipy's splines and rotations another ~0.3 s, in every job's process (a
SLURM array task, a ``python -m bench`` run); loading them costs ~10 ms. The key covers all four
and numpy's and scipy's versions, so an edit to any file of ``avio/sim`` (or the modules it builds
a drive from) makes a new entry rather than returning a stale one.

The folder: ``$AVIO_CACHE_DIR/drives``, else ``$XDG_CACHE_HOME/avio/drives``, else
``~/.cache/avio/drives``; ``AVIO_CACHE_DIR=off`` turns the cache off. An entry that cannot be read
is simulated again and replaced; writes are atomic (a temporary file renamed), so parallel jobs
never read half an entry. Drives rendered to images (``output: images``) are not cached here (their
images have a cache of their own).
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import tempfile
from dataclasses import fields
from importlib import metadata
from pathlib import Path

from avio.calibration import Calibration
from avio.sequence import Sequence, content_hash

CACHE_ENV = "AVIO_CACHE_DIR"
FORMAT_VERSION = 1
_AVIO = Path(__file__).resolve().parents[1]
# what a simulated drive is built from: the simulator and the avio modules it imports
_BUILT_FROM = ("calibration", "errors", "geometry", "reference", "sequence", "tracks")
_SOURCES = (*sorted((_AVIO / "sim").glob("*.py")), *(_AVIO / f"{name}.py" for name in _BUILT_FROM))


def cache_folder() -> Path | None:
    """The drives' cache folder (module docstring), or None when ``AVIO_CACHE_DIR=off``."""
    root = os.environ.get(CACHE_ENV)
    if root is not None and root.strip().lower() == "off":
        return None
    if not root:
        root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "avio"
    return Path(root) / "drives"


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    digest = hashlib.sha256()
    for path in _SOURCES:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    for package in ("numpy", "scipy"):
        digest.update(f"{package}={metadata.version(package)}".encode())
    return digest.hexdigest()


def drive_key(config, seed, true_calibration: Calibration | None, noise_seed) -> str:
    """Hex SHA-256 of everything a simulated drive depends on (module docstring)."""
    arrays = [] if true_calibration is None else [getattr(true_calibration, f.name) for f in fields(Calibration)]
    return content_hash(arrays, {"version": FORMAT_VERSION, "config": repr(config), "seed": repr(seed),
                                 "noise_seed": repr(noise_seed), "code": _code_digest()})


def simulate_cached(config, seed, true_calibration: Calibration | None = None, noise_seed=None) -> Sequence:
    """``avio.sim.simulator.simulate(config, seed, true_calibration=..., noise_seed=...)``, loaded from
    the cache when it holds the drive, else simulated and stored (module docstring)."""
    folder = cache_folder()
    if folder is None or config.output == "images":
        return _simulate(config, seed, true_calibration, noise_seed)
    path = folder / f"drive_{drive_key(config, seed, true_calibration, noise_seed)[:40]}.pkl"
    try:
        with path.open("rb") as stream:
            sequence = pickle.load(stream)
        if isinstance(sequence, Sequence):
            return sequence
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ValueError):
        pass  # absent or unreadable: simulate it (again) below
    sequence = _simulate(config, seed, true_calibration, noise_seed)
    _store(sequence, folder, path)
    return sequence


def _store(sequence: Sequence, folder: Path, path: Path) -> None:
    """Write ``sequence`` to ``path`` atomically; a read-only or full disk only costs the next job a simulation."""
    temporary = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".drive_", delete=False) as stream:
            temporary = stream.name
            pickle.dump(sequence, stream, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(temporary, path)
    except OSError:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)


def _simulate(config, seed, true_calibration, noise_seed) -> Sequence:
    from avio.sim.simulator import simulate  # scipy's splines, only on a cache miss

    return simulate(config, seed, true_calibration=true_calibration, noise_seed=noise_seed)


__all__ = ["CACHE_ENV", "cache_folder", "drive_key", "simulate_cached"]
