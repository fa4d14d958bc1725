"""KLT front end and its cache: real KITTI frames, rendered simulated frames, synthetic textures."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from avio.frontend.cache import CacheError, cache_key, cached_track_images
from avio.frontend.klt import (
    FrontendConfig,
    FrontendError,
    _cells,
    detect_new,
    read_gray,
    track_images,
    track_observations,
    track_pair,
)


@pytest.fixture(scope="module")
def real_paths(shared_data: Path, skip_no_data) -> list[Path]:
    paths = sorted((shared_data / "kitti_gray_2011_09_26").glob("*.png"))
    if len(paths) < 10:
        skip_no_data(f"{shared_data / 'kitti_gray_2011_09_26'} lacks the 10 frames")
    return paths


def _texture_frames(folder: Path, shifts_px: np.ndarray, seed: int = 0, size=(320, 240)) -> list[Path]:
    """PNG frames of one smooth random texture translated by ``shifts_px`` (n, 2) (u, v)."""
    rng = np.random.default_rng(seed)
    w, h = size
    base = cv2.GaussianBlur(rng.uniform(0, 255, (h + 80, w + 80)).astype(np.float32), (0, 0), 2.0)
    base = cv2.normalize(base, None, 0, 255, cv2.NORM_MINMAX)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, (du, dv) in enumerate(shifts_px):
        # Output pixel x shows base pixel x + 40 - shift: the scene moves by +shift.
        M = np.array([[1.0, 0.0, 40.0 - du], [0.0, 1.0, 40.0 - dv]])
        img = cv2.warpAffine(base, M, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
        paths.append(folder / f"{k:04d}.png")
        cv2.imwrite(str(paths[-1]), np.clip(np.round(img), 0, 255).astype(np.uint8))
    return paths


SHIFTS = np.array([[0.0, 0.0], [1.3, 0.4], [2.9, 0.7], [4.2, 1.3], [5.6, 1.5]])


# ---------------------------------------------------------------- real frames


@pytest.mark.data
def test_real_frames_keep_150_tracks_per_pair_with_small_fb_error(real_paths):
    tracks, stats = track_images(real_paths)
    assert (stats.n_inliers >= 150).all()
    assert (stats.fb_median_px < 0.5).all()
    assert (stats.n_inliers <= stats.n_fb_ok).all() and (stats.n_fb_ok <= stats.n_tracked).all()
    assert len(tracks.frame_index) == 8 and (tracks.n_features >= 100).all()


@pytest.mark.data
def test_real_survivors_fit_one_epipolar_geometry(real_paths):
    config = FrontendConfig()
    im0, im1 = read_gray(real_paths[0]), read_gray(real_paths[1])
    uv0 = detect_new(im0, np.zeros((0, 2)), config)
    uv1, keep, _ = track_pair(im0, im1, uv0, config)
    F, _ = cv2.findFundamentalMat(uv0[keep], uv1[keep], cv2.FM_8POINT)
    x0 = np.c_[uv0[keep], np.ones(keep.sum())]
    x1 = np.c_[uv1[keep], np.ones(keep.sum())]
    Fx0, Ftx1 = x0 @ F.T, x1 @ F
    sampson = np.abs(np.sum(x1 * Fx0, 1)) / np.sqrt(Fx0[:, 0] ** 2 + Fx0[:, 1] ** 2 + Ftx1[:, 0] ** 2 + Ftx1[:, 1] ** 2)
    assert np.median(sampson) < 0.3


@pytest.mark.data
def test_a_moving_object_is_rejected_by_ransac(real_paths):
    """Paste a block of frame 0 into frame 1 moved 20 px down: LK follows it (FB passes) but
    it breaks the epipolar geometry of the car's forward motion, so RANSAC drops it."""
    config = FrontendConfig()
    im0, im1 = read_gray(real_paths[0]), read_gray(real_paths[1]).copy()
    rows, cols = slice(80, 220), slice(150, 450)
    im1[100:240, cols] = im0[rows, cols]
    uv0 = detect_new(im0, np.zeros((0, 2)), config)
    uv1, keep, counts = track_pair(im0, im1, uv0, config)
    on_block = (uv0[:, 0] > 170) & (uv0[:, 0] < 430) & (uv0[:, 1] > 100) & (uv0[:, 1] < 200)
    moved = on_block & (np.abs(uv1[:, 1] - uv0[:, 1] - 20.0) < 0.5)
    assert moved.sum() >= 20
    assert keep[moved].mean() < 0.1
    assert counts["n_inliers"] >= 150


# ---------------------------------------------------------------- rendered simulated frames


@pytest.mark.slow
def test_rendered_frames_track_the_true_projections(tmp_path):
    from avio.sim.render import load_projections
    from avio.sim.simulator import SimConfig, simulate

    seq = simulate(SimConfig(duration_s=1.5, output="images"), seed=1, image_dir=tmp_path)
    obs, stats, _ = track_observations(seq.image_paths)
    truth, _ = load_projections(Path(seq.image_paths[0]).parent)
    # Each track's landmark: the true projection nearest to where it was first detected.
    order = np.lexsort((obs.frame_index, obs.track_id))
    f, tid, uv = obs.frame_index[order], obs.track_id[order], obs.uv_px[order]
    first = np.r_[True, tid[1:] != tid[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(tid)), 0))
    tree = cKDTree(np.c_[truth.uv_px, truth.frame_index * 1e4])
    dist, idx = tree.query(np.c_[uv[first], f[first] * 1e4])
    landmark = np.full(tid.max() + 1, -1)
    landmark[tid[first]] = np.where(dist < 1.5, truth.landmark_id[idx], -1)
    # Tracking error: the tracked displacement since detection against the true one.
    lookup = {(int(a), int(b)): i for i, (a, b) in enumerate(zip(truth.frame_index, truth.landmark_id))}
    errors = []
    for i in np.flatnonzero(~first & (landmark[tid] >= 0)):
        j0 = lookup.get((int(f[start[i]]), int(landmark[tid[i]])))
        j1 = lookup.get((int(f[i]), int(landmark[tid[i]])))
        if j0 is not None and j1 is not None:
            errors.append(np.linalg.norm((uv[i] - uv[start[i]]) - (truth.uv_px[j1] - truth.uv_px[j0])))
    errors = np.array(errors)
    assert len(errors) > 500
    assert np.median(errors) < 0.5
    assert (stats.n_inliers > 100).all()


# ---------------------------------------------------------------- synthetic textures


def test_known_translation_is_recovered_to_a_tenth_of_a_pixel(tmp_path):
    paths = _texture_frames(tmp_path, SHIFTS)
    obs, stats, size = track_observations(paths, FrontendConfig(max_per_cell=10))
    assert size == (320, 240)
    order = np.lexsort((obs.frame_index, obs.track_id))
    f, tid, uv = obs.frame_index[order], obs.track_id[order], obs.uv_px[order]
    same = (tid[1:] == tid[:-1]) & (f[1:] == f[:-1] + 1)
    motion = (uv[1:] - uv[:-1])[same]
    true = (SHIFTS[f[1:]] - SHIFTS[f[:-1]])[same]
    assert same.sum() > 300
    assert np.median(np.linalg.norm(motion - true, axis=1)) < 0.1
    # A pure translation has no outliers to reject.
    assert (stats.n_inliers >= 0.95 * stats.n_fb_ok).all()


def test_replenished_corners_respect_the_grid_and_the_spacing(tmp_path):
    image = read_gray(_texture_frames(tmp_path, SHIFTS[:1])[0])
    config = FrontendConfig(grid=(2, 2), max_per_cell=15, min_distance_px=8.0)
    live = detect_new(image, np.zeros((0, 2)), config)[:5]
    live = np.r_[live, np.tile([[40.0, 40.0]], (15, 1)) + np.arange(15)[:, None] * 0.01]  # fill the top-left cell
    new = detect_new(image, live, config)
    counts = np.bincount(_cells(new, image.shape, config.grid), minlength=4)
    live_counts = np.bincount(_cells(live, image.shape, config.grid), minlength=4)
    assert counts[0] == 0
    assert (counts + live_counts <= np.maximum(config.max_per_cell, live_counts)).all()
    assert cKDTree(live).query(new)[0].min() >= config.min_distance_px - 1.0


def test_tracks_are_deterministic_and_capped(tmp_path):
    paths = _texture_frames(tmp_path, SHIFTS)
    config = FrontendConfig(max_features=9, seed=4)
    a, _ = track_images(paths, config)
    b, _ = track_images(paths, config)
    np.testing.assert_array_equal(a.uv_px, b.uv_px)
    assert a.n_features.max() == 9 and len(a.frame_index) == len(paths) - 2


def test_bad_images_are_named(tmp_path):
    paths = _texture_frames(tmp_path / "a", SHIFTS[:3])
    with pytest.raises(FrontendError, match="missing.png: cannot read image"):
        track_images([paths[0], tmp_path / "missing.png", paths[2]])
    small = _texture_frames(tmp_path / "b", SHIFTS[:1], size=(160, 120))[0]
    with pytest.raises(FrontendError, match=r"0000\.png: image size \(160, 120\) differs"):
        track_images([paths[0], small])
    with pytest.raises(FrontendError, match="at least 2 images"):
        track_images(paths[:1])


# ---------------------------------------------------------------- cache


def test_cache_hits_and_returns_the_same_tracks(tmp_path):
    paths = _texture_frames(tmp_path / "img", SHIFTS)
    config = FrontendConfig()
    t1, s1, hit1 = cached_track_images(paths, config, tmp_path / "cache")
    t2, s2, hit2 = cached_track_images(paths, config, tmp_path / "cache")
    assert (hit1, hit2) == (False, True)
    for name in ("frame_index", "uv_px", "valid"):
        np.testing.assert_array_equal(getattr(t1, name), getattr(t2, name))
    np.testing.assert_array_equal(s1.n_inliers, s2.n_inliers)
    files = list((tmp_path / "cache").glob("*.npz"))
    assert len(files) == 1
    np.load(files[0], allow_pickle=False)  # no pickled objects inside


def test_cache_is_invalidated_by_settings_and_image_content(tmp_path):
    paths = _texture_frames(tmp_path / "img", SHIFTS)
    cache = tmp_path / "cache"
    cached_track_images(paths, FrontendConfig(), cache)
    assert cached_track_images(paths, FrontendConfig(fb_max_px=0.5), cache)[2] is False
    image = cv2.imread(str(paths[2]), cv2.IMREAD_GRAYSCALE)
    image[100:110, 100:110] = 255 - image[100:110, 100:110]
    cv2.imwrite(str(paths[2]), image)
    assert cached_track_images(paths, FrontendConfig(), cache)[2] is False
    assert cached_track_images(paths, FrontendConfig(), cache)[2] is True


def test_stat_keys_follow_mtime_and_content_keys_ignore_it(tmp_path):
    paths = _texture_frames(tmp_path / "img", SHIFTS[:3])
    config = FrontendConfig()
    before = cache_key(paths, config, "stat"), cache_key(paths, config, "content")
    st = paths[1].stat()
    os.utime(paths[1], ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    after = cache_key(paths, config, "stat"), cache_key(paths, config, "content")
    assert before[0] != after[0] and before[1] == after[1]
    with pytest.raises(CacheError, match="'content' or 'stat'"):
        cache_key(paths, config, "names")


@pytest.mark.parametrize("damage", [
    lambda p: p.write_bytes(b"not a zip file"),
    lambda p: p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2]),
    lambda p: np.savez(p, key=np.array("another key")),
    lambda p: np.savez(p, key=np.array(str(np.load(p)["key"]))),  # right key, arrays missing
])
def test_a_corrupt_cache_file_is_rebuilt(tmp_path, damage):
    paths = _texture_frames(tmp_path / "img", SHIFTS)
    config = FrontendConfig()
    good, _, _ = cached_track_images(paths, config, tmp_path / "cache")
    (path,) = (tmp_path / "cache").glob("*.npz")
    damage(path)
    rebuilt, _, hit = cached_track_images(paths, config, tmp_path / "cache")
    assert hit is False
    np.testing.assert_array_equal(rebuilt.uv_px, good.uv_px)
    assert cached_track_images(paths, config, tmp_path / "cache")[2] is True


def _rewrite_npz(path: Path, **changes) -> None:
    """Rewrite a cache file with some arrays replaced (None: dropped), the rest as they were."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})


@pytest.mark.parametrize("change", [
    lambda a: {"uv_px": a["uv_px"] + 0.25},  # a valid file, key intact, tracks altered
    lambda a: {"stats_n_inliers": a["stats_n_inliers"][::-1].copy()},
    lambda a: {"checksum": None},  # a file of the previous format, without a checksum
])
def test_a_cache_file_whose_arrays_do_not_match_its_checksum_is_rebuilt(tmp_path, change):
    paths = _texture_frames(tmp_path / "img", SHIFTS)
    config = FrontendConfig()
    good, good_stats, _ = cached_track_images(paths, config, tmp_path / "cache")
    (path,) = (tmp_path / "cache").glob("*.npz")
    with np.load(path, allow_pickle=False) as data:
        _rewrite_npz(path, **change({k: data[k] for k in data.files}))
    rebuilt, stats, hit = cached_track_images(paths, config, tmp_path / "cache")
    assert hit is False
    np.testing.assert_array_equal(rebuilt.uv_px, good.uv_px)
    np.testing.assert_array_equal(stats.n_inliers, good_stats.n_inliers)
    assert cached_track_images(paths, config, tmp_path / "cache")[2] is True


def test_cache_folder_that_is_a_file_is_an_error(tmp_path):
    paths = _texture_frames(tmp_path / "img", SHIFTS[:3])
    (tmp_path / "cache").write_text("")
    with pytest.raises(CacheError, match="cache folder is a file"):
        cached_track_images(paths, FrontendConfig(), tmp_path / "cache")


def test_sequence_gets_tracks_from_its_images_once(tmp_path):
    from avio.sim.simulator import SimConfig, simulate

    seq = simulate(SimConfig(duration_s=0.6, output="images"), seed=2, image_dir=tmp_path / "img")
    assert seq.tracks is None
    from avio.frontend.cache import sequence_with_tracks

    a = sequence_with_tracks(seq, FrontendConfig(max_features=20), tmp_path / "cache")
    b = sequence_with_tracks(seq, FrontendConfig(max_features=20), tmp_path / "cache")
    assert a.tracks.uv_px.shape[0] == seq.n_frames - 2 and a.tracks.n_features.min() > 5
    np.testing.assert_array_equal(a.tracks.uv_px, b.tracks.uv_px)
    assert a.meta["frontend"]["max_features"] == 20 and len(list((tmp_path / "cache").glob("*.npz"))) == 1
    with pytest.raises(CacheError, match="has no images"):
        sequence_with_tracks(replace(seq, image_paths=None), FrontendConfig(), tmp_path / "cache")
