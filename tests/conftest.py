"""Fixtures shared by the whole suite."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """The real-data folder: $AVIO_DATA, else ../shared/data relative to the repository root."""
    return Path(os.environ.get("AVIO_DATA", REPO_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of the real data; skips the test (with the path tried) when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data folder {path} is absent (set AVIO_DATA to use another)")
    return path


@pytest.fixture
def load_script(request):
    """``load_script("name")``: the script ``name.py`` of the folder this test mirrors
    (tests/benchmarks/… -> benchmarks/name.py, tests/studies/objective/… -> studies/objective/name.py).
    Scripts are files, not a package, so they load by path."""
    folder = REPO_ROOT / Path(request.fspath).parent.relative_to(REPO_ROOT / "tests")

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, folder / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load
