"""The default data folder: AVIO_DATA always; ../shared/data only from a source checkout; else a
user folder (a wheel's install must not look inside site-packages)."""

from __future__ import annotations

from pathlib import Path

from avio.datasets import paths

REPO = Path(__file__).resolve().parents[3]


def test_a_checkout_is_recognised_by_its_pyproject(tmp_path):
    assert paths.is_checkout(REPO)
    assert not paths.is_checkout(tmp_path)


def test_from_a_checkout_the_default_is_shared_data_beside_it(monkeypatch):
    monkeypatch.delenv("AVIO_DATA", raising=False)
    monkeypatch.setattr(paths, "is_checkout", lambda root=paths.PACKAGE_PARENT: True)
    assert paths.data_root() == paths.PACKAGE_PARENT.parent / "shared" / "data"


def test_installed_the_default_is_a_user_folder(monkeypatch, tmp_path):
    monkeypatch.delenv("AVIO_DATA", raising=False)
    monkeypatch.setattr(paths, "is_checkout", lambda root=paths.PACKAGE_PARENT: False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert paths.data_root() == tmp_path / "xdg" / "avio-bench"
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert paths.data_root() == tmp_path / "home" / ".local" / "share" / "avio-bench"
    assert "site-packages" not in str(paths.data_root())


def test_avio_data_always_wins(monkeypatch, tmp_path):
    monkeypatch.setenv("AVIO_DATA", str(tmp_path))
    for checkout in (True, False):
        monkeypatch.setattr(paths, "is_checkout", lambda root=paths.PACKAGE_PARENT, c=checkout: c)
        assert paths.data_root() == tmp_path


def test_the_problems_default_follows_it(monkeypatch, tmp_path):
    from bench.problems.vio import default_data_dir

    monkeypatch.delenv("AVIO_DATA", raising=False)
    monkeypatch.setattr(paths, "is_checkout", lambda root=paths.PACKAGE_PARENT: False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path))
    assert default_data_dir() == tmp_path / "avio-bench"
    assert default_data_dir(str(tmp_path / "mine")) == tmp_path / "mine"  # problem.params.data_dir first
    monkeypatch.setenv("AVIO_DATA", str(tmp_path / "env"))
    assert default_data_dir() == tmp_path / "env"
