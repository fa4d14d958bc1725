"""Run the front end once per image sequence and keep the result on disk (NPZ, no pickle).

The key is a SHA-256 over the front-end settings, a format version, and either the images'
content (default; robust to copies and touches) or their paths, sizes and mtimes (cheaper for
long drives). A different key means a different file, so changed images or settings never
read a stale result; an unreadable or inconsistent file is rebuilt (and overwritten).
Each file also carries a SHA-256 of its own arrays (``checksum``), checked on load, so a file
whose contents changed after it was written (bit rot, a partial copy, an edit) is rebuilt too.
Files are written to a temporary name and renamed, so a crash never leaves half a file.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import zipfile
from dataclasses import fields, replace
from pathlib import Path
from typing import Literal

import numpy as np

from avio.errors import AvioError
from avio.frontend.klt import FrontendConfig, FrontendStats, track_images
from avio.sequence import Sequence, TripletTracks, content_hash

CACHE_FORMAT_VERSION = 2  # 2: content checksum in the file
_TRACK_FIELDS = ("frame_index", "uv_px", "valid")


class CacheError(AvioError):
    """The cache folder cannot be used (e.g. it is a file); the message names it."""


def cache_key(
    paths: list[str | Path], config: FrontendConfig, mode: Literal["content", "stat"] = "content"
) -> str:
    """Hex SHA-256 identifying (images, settings, format version)."""
    digest = hashlib.sha256()
    digest.update(json.dumps({"version": CACHE_FORMAT_VERSION, "config": config.as_dict()},
                             sort_keys=True).encode())
    for path in paths:
        path = Path(path)
        if mode == "content":
            digest.update(hashlib.sha256(path.read_bytes()).digest())
        elif mode == "stat":
            st = path.stat()
            digest.update(f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}".encode())
        else:
            raise CacheError(f"cache key mode must be 'content' or 'stat', got {mode!r}")
    return digest.hexdigest()


def _array_names() -> list[str]:
    """The arrays of a cache file, in the order the checksum reads them."""
    return [*_TRACK_FIELDS, *("stats_" + f.name for f in fields(FrontendStats))]


def _checksum(arrays: dict[str, np.ndarray], key: str) -> str:
    """Hex SHA-256 of the file's arrays (dtype, shape, bytes) and its key."""
    return content_hash([np.asarray(arrays[k]) for k in _array_names()], {"key": key})


def _load(path: Path, key: str) -> tuple[TripletTracks, FrontendStats] | None:
    """The cached result, or None when the file is absent, unreadable, not for ``key`` or its
    arrays do not match its checksum."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["key"]) != key:
                return None
            if str(data["checksum"]) != _checksum({k: data[k] for k in _array_names()}, key):
                return None
            tracks = TripletTracks(**{k: data[k] for k in _TRACK_FIELDS})
            stats = FrontendStats(**{f.name: data["stats_" + f.name] for f in fields(FrontendStats)})
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, AvioError):
        # A truncated, foreign or pre-checksum file (numpy's ValueError, or arrays that TripletTracks
        # refuses with a SequenceError): rebuilding is the cure, so it is not raised.
        return None
    return tracks, stats


def _save(path: Path, key: str, tracks: TripletTracks, stats: FrontendStats) -> None:
    arrays = {k: getattr(tracks, k) for k in _TRACK_FIELDS}
    arrays.update({"stats_" + f.name: getattr(stats, f.name) for f in fields(FrontendStats)})
    handle, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(handle, "wb") as out:
            np.savez(out, key=np.array(key), checksum=np.array(_checksum(arrays, key)), **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def cached_track_images(
    paths: list[str | Path], config: FrontendConfig, cache_dir: str | Path,
    key_mode: Literal["content", "stat"] = "content",
) -> tuple[TripletTracks, FrontendStats, bool]:
    """``track_images(paths, config)`` through a cache in ``cache_dir``:
    ``(tracks, stats, hit)`` with ``hit`` True when read from disk."""
    cache_dir = Path(cache_dir)
    if cache_dir.exists() and not cache_dir.is_dir():
        raise CacheError(f"{cache_dir}: cache folder is a file")
    cache_dir.mkdir(parents=True, exist_ok=True)
    key = cache_key(paths, config, key_mode)
    path = cache_dir / f"frontend_{key[:32]}.npz"
    cached = _load(path, key)
    if cached is not None:
        return cached[0], cached[1], True
    tracks, stats = track_images(paths, config)
    _save(path, key, tracks, stats)
    return tracks, stats, False


def sequence_with_tracks(
    sequence: Sequence, config: FrontendConfig, cache_dir: str | Path,
    key_mode: Literal["content", "stat"] = "content",
) -> Sequence:
    """``sequence`` with tracks from its images (front end run once, then read from the cache);
    the front-end settings and the cache key go into ``meta``."""
    if not sequence.image_paths:
        raise CacheError(f"sequence {sequence.name!r} has no images to track")
    if len(sequence.image_paths) != sequence.n_frames:
        raise CacheError(f"sequence {sequence.name!r}: {len(sequence.image_paths)} images for "
                         f"{sequence.n_frames} frames")
    tracks, stats, _ = cached_track_images(list(sequence.image_paths), config, cache_dir, key_mode)
    meta = {**sequence.meta, "frontend": config.as_dict(),
            "frontend_key": cache_key(list(sequence.image_paths), config, key_mode),
            "frontend_inliers_per_pair": stats.n_inliers.tolist()}
    return replace(sequence, tracks=tracks, meta=meta)
