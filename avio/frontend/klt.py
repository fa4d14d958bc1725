"""The KLT front end: grayscale images -> feature tracks over frame triplets (OpenCV).

Per consecutive pair (k-1, k): pyramidal Lucas–Kanade (``cv2.calcOpticalFlowPyrLK``) forward
and backward; a track survives when both directions converge, it ends inside the image, and it
returns to within ``fb_max_px`` of where it started (forward–backward check). The survivors
then pass RANSAC on the fundamental matrix in pixels (``cv2.findFundamentalMat``): it needs
no calibration, so the tracks stay calibration-independent and are computed once per sequence.
Frame k is then replenished with Shi–Tomasi corners (``cv2.goodFeaturesToTrack``) away from the
live tracks, bucketed over a grid so features spread over the image.

Observations ``(frame, track id, uv)`` go to ``avio.tracks.triplets_from_observations``.
Pixel coordinates: u right, v down, origin at the centre of the top-left pixel (OpenCV's).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from avio.errors import AvioError
from avio.sequence import TripletTracks
from avio.tracks import rank_in_groups, triplets_from_observations


class FrontendError(AvioError):
    """An image cannot be read or the images disagree; the message names the file."""


@dataclass(frozen=True)
class FrontendConfig:
    """Settings of the KLT front end (all pixel values in pixels of the input images).

    max_corners: Shi–Tomasi candidates asked for per detection.
    quality_level, min_distance_px, block_size: ``cv2.goodFeaturesToTrack`` settings.
    grid: (rows, cols) bucketing grid; max_per_cell: live tracks kept per cell.
    win_size_px, max_level: LK window (square side) and pyramid levels above the base. 15 px:
        on rendered frames the median drift since detection is 0.13/0.18/0.32 px for 11/15/21 px
        windows (neighbouring blobs at other depths pull larger windows), while on the real
        frames all three give the same epipolar residual (median Sampson 0.09 px).
    fb_max_px: largest accepted forward–backward error.
    ransac_threshold_px, ransac_confidence: ``cv2.findFundamentalMat`` (FM_RANSAC) settings.
    border_px: tracks closer than this to the image edge are dropped.
    max_features: features per triplet handed to the filter (bucketed; None = all).
    seed: seeds the generator of the per-triplet feature choice.
    """

    max_corners: int = 2000
    quality_level: float = 0.01
    min_distance_px: float = 10.0
    block_size: int = 7
    grid: tuple[int, int] = (4, 8)
    max_per_cell: int = 20
    win_size_px: int = 15
    max_level: int = 3
    fb_max_px: float = 1.0
    ransac_threshold_px: float = 1.0
    ransac_confidence: float = 0.999
    border_px: int = 5
    max_features: int | None = None
    seed: int = 0

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class FeatureObservations:
    """Tracked features: frame_index (m,) int, track_id (m,) int, uv_px (m, 2) pixels."""

    frame_index: np.ndarray
    track_id: np.ndarray
    uv_px: np.ndarray


@dataclass(frozen=True)
class FrontendStats:
    """Per consecutive pair (k-1, k), arrays (n_frames - 1,):

    n_tracked: tracks LK converged on both ways; n_fb_ok: of those, passing the FB check;
    n_inliers: of those, RANSAC inliers (the tracks that survive the pair);
    fb_median_px: median FB error of the LK-converged tracks; n_new: corners added in frame k.
    """

    n_tracked: np.ndarray
    n_fb_ok: np.ndarray
    n_inliers: np.ndarray
    fb_median_px: np.ndarray
    n_new: np.ndarray


def read_gray(path: str | Path) -> np.ndarray:
    """(height, width) uint8 image; FrontendError if missing or unreadable."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise FrontendError(f"{path}: cannot read image (missing or not an image)")
    return image


def _cells(uv: np.ndarray, shape: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    rows, cols = grid
    h, w = shape
    c = np.clip((uv[:, 0] * cols / w).astype(np.int64), 0, cols - 1)
    r = np.clip((uv[:, 1] * rows / h).astype(np.int64), 0, rows - 1)
    return r * cols + c


def detect_new(image: np.ndarray, live_uv: np.ndarray, config: FrontendConfig) -> np.ndarray:
    """(n_new, 2) Shi–Tomasi corners away from ``live_uv`` (n, 2), filling each grid cell up to
    ``max_per_cell`` (strongest first)."""
    h, w = image.shape
    mask = np.full((h, w), 255, np.uint8)
    b = config.border_px
    mask[:b], mask[h - b:], mask[:, :b], mask[:, w - b:] = 0, 0, 0, 0
    if len(live_uv):
        # Zero a disc of min_distance around each live track: mark the pixels, then erode.
        ui = np.clip(np.round(live_uv).astype(int), 0, [w - 1, h - 1])
        occupied = np.zeros((h, w), np.uint8)
        occupied[ui[:, 1], ui[:, 0]] = 255
        r = int(np.ceil(config.min_distance_px))
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        mask[cv2.dilate(occupied, disc) > 0] = 0
    corners = cv2.goodFeaturesToTrack(
        image, maxCorners=config.max_corners, qualityLevel=config.quality_level,
        minDistance=config.min_distance_px, mask=mask, blockSize=config.block_size,
    )
    if corners is None:
        return np.zeros((0, 2))
    corners = corners.reshape(-1, 2).astype(float)
    n_cells = config.grid[0] * config.grid[1]
    room = config.max_per_cell - np.bincount(_cells(live_uv, (h, w), config.grid), minlength=n_cells)
    cell = _cells(corners, (h, w), config.grid)
    # goodFeaturesToTrack returns strongest first; a stable sort by cell keeps that order.
    order = np.argsort(cell, kind="stable")
    rank = np.empty(len(cell), np.int64)
    rank[order] = rank_in_groups(cell[order])
    return corners[rank < room[cell]]


def track_pair(
    image0: np.ndarray, image1: np.ndarray, uv0: np.ndarray, config: FrontendConfig
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Track ``uv0`` (n, 2) from image0 into image1: ``(uv1 (n, 2), keep (n,) bool, counts)``.

    keep = LK converged both ways, inside the border, FB error <= fb_max_px, RANSAC-F inlier.
    """
    n = len(uv0)
    counts = {"n_tracked": 0, "n_fb_ok": 0, "n_inliers": 0, "fb_median_px": np.nan}
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, bool), counts
    lk = dict(winSize=(config.win_size_px, config.win_size_px), maxLevel=config.max_level,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    p0 = uv0.astype(np.float32).reshape(-1, 1, 2)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(image0, image1, p0, None, **lk)
    p0b, st0, _ = cv2.calcOpticalFlowPyrLK(image1, image0, p1, None, **lk)
    uv1 = p1.reshape(-1, 2).astype(float)
    fb = np.linalg.norm(p0b.reshape(-1, 2) - p0.reshape(-1, 2), axis=1)
    h, w = image1.shape
    b = config.border_px
    inside = (uv1[:, 0] >= b) & (uv1[:, 0] < w - b) & (uv1[:, 1] >= b) & (uv1[:, 1] < h - b)
    tracked = (st1.ravel() == 1) & (st0.ravel() == 1) & inside
    keep = tracked & (fb <= config.fb_max_px)
    counts.update(n_tracked=int(tracked.sum()), n_fb_ok=int(keep.sum()),
                  fb_median_px=float(np.median(fb[tracked])) if tracked.any() else np.nan)
    if keep.sum() >= 8:
        _, inlier = cv2.findFundamentalMat(uv0[keep], uv1[keep], cv2.FM_RANSAC,
                                           config.ransac_threshold_px, config.ransac_confidence)
        if inlier is None:  # degenerate configuration: no model, keep nothing
            inlier = np.zeros(int(keep.sum()), np.uint8)
        keep[np.flatnonzero(keep)] = inlier.ravel().astype(bool)
    else:
        keep[:] = False
    counts["n_inliers"] = int(keep.sum())
    return uv1, keep, counts


def track_observations(
    paths: list[str | Path], config: FrontendConfig = FrontendConfig()
) -> tuple[FeatureObservations, FrontendStats, tuple[int, int]]:
    """Run the front end over the images in order: ``(observations, stats, (width, height))``.

    The loop runs over frames, which are sequential by nature (each pair needs the last one's
    tracks); everything within a frame is vectorised.
    """
    if len(paths) < 2:
        raise FrontendError(f"need at least 2 images, got {len(paths)}")
    prev = read_gray(paths[0])
    uv = detect_new(prev, np.zeros((0, 2)), config)
    ids = np.arange(len(uv))
    next_id = len(uv)
    obs_f, obs_id, obs_uv = [np.zeros(len(uv), np.int64)], [ids], [uv]
    stats = {k: [] for k in FrontendStats.__dataclass_fields__}
    for k in range(1, len(paths)):
        image = read_gray(paths[k])
        if image.shape != prev.shape:
            raise FrontendError(f"{paths[k]}: image size {image.shape[::-1]} differs from "
                                f"{paths[0]} {prev.shape[::-1]}")
        uv1, keep, counts = track_pair(prev, image, uv, config)
        uv, ids = uv1[keep], ids[keep]
        new = detect_new(image, uv, config)
        uv = np.concatenate([uv, new])
        ids = np.concatenate([ids, np.arange(next_id, next_id + len(new))])
        next_id += len(new)
        obs_f.append(np.full(len(uv), k, np.int64))
        obs_id.append(ids)
        obs_uv.append(uv)
        for key, value in counts.items():
            stats[key].append(value)
        stats["n_new"].append(len(new))
        prev = image
    obs = FeatureObservations(np.concatenate(obs_f), np.concatenate(obs_id), np.concatenate(obs_uv))
    stats = FrontendStats(**{k: np.asarray(v) for k, v in stats.items()})
    return obs, stats, (prev.shape[1], prev.shape[0])


def track_images(
    paths: list[str | Path], config: FrontendConfig = FrontendConfig()
) -> tuple[TripletTracks, FrontendStats]:
    """Images -> (TripletTracks over frames (k-2, k-1, k), FrontendStats); at most
    ``config.max_features`` per triplet, bucketed with a generator seeded ``config.seed``."""
    obs, stats, size = track_observations(paths, config)
    tracks = triplets_from_observations(
        obs.frame_index, obs.track_id, obs.uv_px, len(paths), max_features=config.max_features,
        rng=np.random.default_rng(config.seed), image_size_px=size, grid=config.grid,
    )
    return tracks, stats
