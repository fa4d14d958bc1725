import numpy as np
import pytest

from avio.tracks import TracksError, bucket_select, triplets_from_observations


def _obs(rows):
    """rows of (frame, track, u, v) -> arrays."""
    a = np.array(rows, float)
    return a[:, 0].astype(int), a[:, 1].astype(int), a[:, 2:4]


def test_triplets_keep_only_tracks_seen_in_three_consecutive_frames():
    f, tid, uv = _obs(
        [
            (0, 0, 10, 11), (1, 0, 12, 13), (2, 0, 14, 15), (3, 0, 16, 17),  # seen throughout
            (0, 1, 50, 51), (1, 1, 52, 53), (3, 1, 56, 57),  # gap at frame 2
            (1, 2, 90, 91), (2, 2, 92, 93), (3, 2, 94, 95),  # starts at frame 1
        ]
    )
    tracks, ids = triplets_from_observations(f, tid, uv, n_frames=5, return_track_ids=True)
    assert tracks.frame_index.tolist() == [2, 3, 4]
    assert tracks.n_features.tolist() == [1, 2, 0]
    assert ids[0, 0] == 0 and sorted(ids[1][tracks.valid[1]].tolist()) == [0, 2]
    np.testing.assert_array_equal(tracks.uv_px[0, 0], [[10, 11], [12, 13], [14, 15]])
    row = int(np.nonzero(ids[1] == 2)[0][0])
    np.testing.assert_array_equal(tracks.uv_px[1, row], [[90, 91], [92, 93], [94, 95]])
    assert np.all(tracks.uv_px[~tracks.valid] == 0)


def test_result_does_not_depend_on_observation_order():
    rng = np.random.default_rng(3)
    n_frames, n_tracks = 12, 40
    f = np.repeat(np.arange(n_frames), n_tracks)
    tid = np.tile(np.arange(n_tracks), n_frames)
    keep = rng.random(len(f)) < 0.8
    f, tid = f[keep], tid[keep]
    uv = rng.uniform(0, 300, (len(f), 2))
    a = triplets_from_observations(f, tid, uv, n_frames)
    perm = rng.permutation(len(f))
    b = triplets_from_observations(f[perm], tid[perm], uv[perm], n_frames)
    np.testing.assert_array_equal(a.uv_px, b.uv_px)
    np.testing.assert_array_equal(a.valid, b.valid)


def test_fewer_than_three_frames_give_no_triplets():
    tracks = triplets_from_observations(np.array([0, 1]), np.array([0, 0]), np.zeros((2, 2)), n_frames=2)
    assert tracks.uv_px.shape[0] == 0 and tracks.frame_index.shape == (0,)


@pytest.mark.parametrize(
    "frame, track, uv, match",
    [
        ([0, 0], [1, 1], [[0, 0], [1, 1]], "observed twice in frame 0"),
        ([0, 7], [1, 1], [[0, 0], [1, 1]], "frame 7 outside"),
        ([0.0, 1.0], [1, 1], [[0, 0], [1, 1]], "must be integers"),
        ([0, 1], [1, 1], [[0, 0], [np.nan, 1]], "non-finite"),
        ([0, 1], [1, 1], [[0, 0, 0], [1, 1, 1]], "uv_px"),
    ],
)
def test_bad_observations_raise_with_reason(frame, track, uv, match):
    with pytest.raises(TracksError, match=match):
        triplets_from_observations(np.array(frame), np.array(track), np.array(uv, float), n_frames=5)


def test_bucketing_visits_every_cell_before_a_second_feature_from_any():
    rng = np.random.default_rng(0)
    width, height, rows, cols = 800, 400, 4, 8
    # One feature in the centre of each of the 32 cells, plus 100 crowded into cell (0, 0).
    cu, cv = np.meshgrid((np.arange(cols) + 0.5) * width / cols, (np.arange(rows) + 0.5) * height / rows)
    uv = np.vstack([np.c_[cu.ravel(), cv.ravel()], rng.uniform(0, 50, (100, 2))])
    chosen = bucket_select(np.zeros(len(uv), int), uv, 40, rng, (width, height), (rows, cols))
    assert chosen.sum() == 40
    # Cells 1..31 hold one feature each: all taken; the crowded cell 0 (101 features) gets the other 9.
    assert chosen[1:32].all(), "every cell contributes before the crowded cell gets more"
    assert chosen[[0] + list(range(32, 132))].sum() == 9


def test_bucketing_is_deterministic_for_a_seed_and_caps_each_triplet():
    rng = np.random.default_rng(5)
    n_frames, n_tracks = 8, 120
    f = np.repeat(np.arange(n_frames), n_tracks)
    tid = np.tile(np.arange(n_tracks), n_frames)
    uv = np.tile(rng.uniform(0, 1000, (n_tracks, 2)) * [1.0, 0.3], (n_frames, 1))
    kw = dict(image_size_px=(1000, 300))
    a = triplets_from_observations(f, tid, uv, n_frames, 30, np.random.default_rng(1), **kw)
    b = triplets_from_observations(f, tid, uv, n_frames, 30, np.random.default_rng(1), **kw)
    c = triplets_from_observations(f, tid, uv, n_frames, 30, np.random.default_rng(2), **kw)
    np.testing.assert_array_equal(a.uv_px, b.uv_px)
    assert not np.array_equal(a.uv_px, c.uv_px)
    assert a.n_features.tolist() == [30] * (n_frames - 2)
    assert a.uv_px.shape == (n_frames - 2, 30, 3, 2)
