import numpy as np
import pytest

from avio.export import ExportError, read_kitti, read_tum, write_kitti, write_tum
from avio.geometry import so3_exp


def _trajectory(N=25, seed=0):
    rng = np.random.default_rng(seed)
    t = 46535.0 + 0.1036 * np.arange(N)
    p = np.cumsum(rng.normal(0, 1, (N, 3)), axis=0) * 10
    R = so3_exp(rng.normal(0, 1.5, (N, 3)))
    return t, p, R


def test_tum_round_trip(tmp_path):
    t, p, R = _trajectory()
    write_tum(tmp_path / "est.tum", t, p, R)
    t2, p2, R2 = read_tum(tmp_path / "est.tum")
    np.testing.assert_allclose(t2, t, atol=1e-9)
    np.testing.assert_allclose(p2, p, atol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    # evo's TUM reader wants 8 columns and the scalar of the quaternion last.
    first = (tmp_path / "est.tum").read_text().splitlines()[1].split()
    assert len(first) == 8
    qw = float(first[7])
    assert np.isclose(abs(qw), np.sqrt(1 + np.trace(R[0])) / 2, atol=1e-9)


def test_kitti_round_trip(tmp_path):
    _, p, R = _trajectory(seed=1)
    write_kitti(tmp_path / "est.txt", p, R)
    p2, R2 = read_kitti(tmp_path / "est.txt")
    np.testing.assert_allclose(p2, p, atol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-11)
    row = np.array((tmp_path / "est.txt").read_text().splitlines()[3].split(), float)
    np.testing.assert_allclose(row.reshape(3, 4), np.c_[R[3], p[3]], atol=1e-9)


def test_non_finite_trajectory_is_refused(tmp_path):
    t, p, R = _trajectory()
    p[4, 1] = np.nan
    with pytest.raises(ExportError, match="non-finite"):
        write_kitti(tmp_path / "x.txt", p, R)
    assert not (tmp_path / "x.txt").exists()


def test_bad_line_names_file_and_line(tmp_path):
    f = tmp_path / "bad.tum"
    f.write_text("# header\n0 1 2 3 0 0 0 1\n1 2 3\n")
    with pytest.raises(ExportError, match=r"bad.tum:3: expected 8"):
        read_tum(f)


def test_numbers_read_back_bit_for_bit(tmp_path):
    t, p, R = _trajectory(seed=2)
    write_kitti(tmp_path / "est.kitti", p, R)
    p2, R2 = read_kitti(tmp_path / "est.kitti")
    assert np.array_equal(p2, p) and np.array_equal(R2, R)
    write_tum(tmp_path / "est.tum", t, p, R)
    _, p3, _ = read_tum(tmp_path / "est.tum")
    assert np.array_equal(p3, p)
