"""Feature observations (frame, track, pixel) -> tracks over consecutive frame triplets.

The filter consumes features seen in three consecutive images (docs/model.md, "Measurement
chain"): for each frame k >= 2, every track observed in frames k-2, k-1 and k. Optionally a fixed
number of them is chosen per triplet by bucketing the image of frame k into a grid and taking
features from the cells in turn, so that the chosen features spread over the image (the 4x8
bucketing of the reference MATLAB implementation).
"""

from __future__ import annotations

import numpy as np

from avio.errors import AvioError
from avio.sequence import TripletTracks


class TracksError(AvioError):
    """Observations cannot be turned into triplet tracks; the message says which and why."""


def _validated(frame_index, track_id, uv_px, n_frames):
    frame_index = np.asarray(frame_index)
    track_id = np.asarray(track_id)
    uv_px = np.asarray(uv_px, float)
    m = len(frame_index)
    if frame_index.ndim != 1 or track_id.shape != (m,) or uv_px.shape != (m, 2):
        raise TracksError(
            f"avio.tracks: need frame_index (m,), track_id (m,), uv_px (m, 2); got "
            f"{frame_index.shape}, {track_id.shape}, {uv_px.shape}"
        )
    if m and not (np.issubdtype(frame_index.dtype, np.integer) and np.issubdtype(track_id.dtype, np.integer)):
        raise TracksError(
            f"avio.tracks: frame_index and track_id must be integers, got {frame_index.dtype}, {track_id.dtype}"
        )
    if m and (frame_index.min() < 0 or frame_index.max() >= n_frames):
        bad = int(np.argmax((frame_index < 0) | (frame_index >= n_frames)))
        raise TracksError(
            f"avio.tracks: observation {bad} has frame {int(frame_index[bad])} outside [0, {n_frames})"
        )
    if not np.all(np.isfinite(uv_px)):
        bad = int(np.argmax(~np.all(np.isfinite(uv_px), axis=1)))
        raise TracksError(f"avio.tracks: observation {bad} has a non-finite pixel {uv_px[bad]}")
    return frame_index.astype(np.int64), track_id.astype(np.int64), uv_px


def rank_in_groups(sorted_group: np.ndarray) -> np.ndarray:
    """(c,) position of each element within its run of equal values (input sorted by group)."""
    c = len(sorted_group)
    if c == 0:
        return np.zeros(0, np.int64)
    start = np.r_[True, sorted_group[1:] != sorted_group[:-1]]
    start_pos = np.maximum.accumulate(np.where(start, np.arange(c), 0))
    return np.arange(c) - start_pos


def bucket_select(
    triplet: np.ndarray,
    uv_px: np.ndarray,
    max_features: int,
    rng: np.random.Generator,
    image_size_px: tuple[int, int],
    grid: tuple[int, int] = (4, 8),
) -> np.ndarray:
    """Choose at most ``max_features`` candidates per triplet, spread over an image grid.

    triplet: (c,) triplet number of each candidate; uv_px: (c, 2) its pixel in the image the
    grid covers (frame k); image_size_px: (width, height); grid: (rows, cols).
    Cells are visited in turn (a random cell order per round) and a random candidate taken from
    each, so every cell gets a share before any cell gets a second one.
    Returns a (c,) bool mask of the chosen candidates; deterministic for a given ``rng`` state.
    """
    rows, cols = grid
    width, height = image_size_px
    col = np.clip((uv_px[:, 0] * cols / width).astype(np.int64), 0, cols - 1)
    row = np.clip((uv_px[:, 1] * rows / height).astype(np.int64), 0, rows - 1)
    cell = row * cols + col
    n_cells, c = rows * cols, len(triplet)
    if c == 0:
        return np.zeros(0, bool)
    # Single int64 sort keys (group, then a random permutation as tie-break): faster than lexsort.
    group = triplet * n_cells + cell
    order = np.argsort(group * c + rng.permutation(c), kind="stable")
    rank = np.empty(c, np.int64)
    rank[order] = rank_in_groups(group[order])
    # A random order of the cells per triplet sets which cell goes first in every round.
    cell_rank = np.argsort(rng.random((int(triplet.max()) + 1, n_cells)), axis=1).argsort(axis=1)
    order = np.argsort((triplet * (rank.max() + 1) + rank) * n_cells + cell_rank[triplet, cell], kind="stable")
    chosen = np.zeros(c, bool)
    chosen[order] = rank_in_groups(triplet[order]) < max_features
    return chosen


def triplets_from_observations(
    frame_index: np.ndarray,
    track_id: np.ndarray,
    uv_px: np.ndarray,
    n_frames: int,
    max_features: int | None = None,
    rng: np.random.Generator | None = None,
    *,
    image_size_px: tuple[int, int] | None = None,
    grid: tuple[int, int] = (4, 8),
    return_track_ids: bool = False,
) -> TripletTracks | tuple[TripletTracks, np.ndarray]:
    """Tracks seen in three consecutive frames, one triplet per frame k = 2 .. n_frames-1.

    frame_index: (m,) int frame of each observation, in [0, n_frames).
    track_id: (m,) int identity of the tracked feature (a track seen twice in one frame is an error).
    uv_px: (m, 2) pixel coordinates (u right, v down).
    max_features: if given, at most this many features per triplet, chosen by bucketing the
        image of frame k into ``grid`` (rows, cols) cells of ``image_size_px`` (width, height;
        default: the extent of all observations) using ``rng`` (default: a generator seeded 0,
        so the choice is still deterministic).
    Returns TripletTracks with ``frame_index = arange(2, n_frames)`` and features padded to the
    largest count of any triplet; with ``return_track_ids`` also the (n_triplets, n_feat) track
    ids (-1 for padding). Features within a triplet are ordered by track id.
    """
    frame_index, track_id, uv_px = _validated(frame_index, track_id, uv_px, n_frames)
    n_trip = max(int(n_frames) - 2, 0)
    order = np.lexsort((frame_index, track_id))
    f, tid, uv = frame_index[order], track_id[order], uv_px[order]
    same_track = tid[1:] == tid[:-1]
    dup = same_track & (f[1:] == f[:-1])
    if np.any(dup):
        i = order[int(np.argmax(dup)) + 1]
        raise TracksError(
            f"avio.tracks: track {int(track_id[i])} is observed twice in frame {int(frame_index[i])} "
            f"(observation {int(i)})"
        )
    # In (track, frame) order, a triplet ends at i when i-1 and i-2 are the same track one and two frames earlier.
    consecutive = same_track & (f[1:] - f[:-1] == 1)
    end = np.nonzero(consecutive[1:] & consecutive[:-1])[0] + 2
    triplet = f[end] - 2
    uv3 = np.stack([uv[end - 2], uv[end - 1], uv[end]], axis=1)
    ids = tid[end]

    if max_features is not None and len(end):
        if max_features < 1:
            raise TracksError(f"avio.tracks: max_features must be >= 1, got {max_features}")
        if image_size_px is None:
            image_size_px = (float(uv_px[:, 0].max()) + 1.0, float(uv_px[:, 1].max()) + 1.0)
        rng = np.random.default_rng(0) if rng is None else rng
        keep = bucket_select(triplet, uv3[:, 2], int(max_features), rng, image_size_px, grid)
        triplet, uv3, ids = triplet[keep], uv3[keep], ids[keep]
    slot_order = np.lexsort((ids, triplet))
    triplet, uv3, ids = triplet[slot_order], uv3[slot_order], ids[slot_order]
    slot = rank_in_groups(triplet)
    n_feat = int(slot.max()) + 1 if len(slot) else 0
    out_uv = np.zeros((n_trip, n_feat, 3, 2))
    valid = np.zeros((n_trip, n_feat), bool)
    out_ids = np.full((n_trip, n_feat), -1, np.int64)
    out_uv[triplet, slot] = uv3
    valid[triplet, slot] = True
    out_ids[triplet, slot] = ids
    tracks = TripletTracks(frame_index=np.arange(2, 2 + n_trip), uv_px=out_uv, valid=valid)
    return (tracks, out_ids) if return_track_ids else tracks
