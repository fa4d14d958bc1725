"""The avio package of another commit, taken from the git history and imported under a private
name, so that a test can run today's filter beside a frozen one (the machinery of
benchmarks/ab_kernel.py, which does the same for timings).

``load(commit)`` extracts ``avio/`` of ``commit`` (``git archive``) into
``<tmp>/avio_ref_<sha12>/_avio_ref_<sha12>/``, rewrites its ``import avio`` / ``from avio``
lines to the private name (every module of the copy imports only the copy: geometry,
calibration and preparation are frozen with the kernel) and imports it. The folder is made once
per commit and kept: numba's cache of the copy's kernel lives in it (``cache=True``), so only the
first run on a machine pays the copy's compile. ``unavailable(commit)`` says why it cannot be
done (no git, not a checkout, a shallow clone or an sdist without that commit), or None.
"""

from __future__ import annotations

import importlib
import io
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[3]
_IMPORT = re.compile(r"^(\s*)(from|import) avio\b", re.MULTILINE)


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True)


def unavailable(commit: str) -> str | None:
    """Why ``commit``'s avio cannot be loaded from this checkout, or None when it can."""
    if shutil.which("git") is None:
        return "git is not installed"
    if _git("rev-parse", "--git-dir").returncode != 0:
        return f"{REPO} is not a git checkout (an sdist?)"
    if _git("cat-file", "-e", f"{commit}^{{commit}}").returncode != 0:
        return f"commit {commit} is not in this checkout's history (a shallow clone? git fetch --unshallow)"
    return None


def _extract(sha: str, root: Path, name: str) -> None:
    """avio/ of ``sha`` as package ``name`` in ``root`` (made in a sibling folder, then renamed, so
    a half-made folder is never seen and two processes cannot mix their files)."""
    blob = subprocess.run(["git", "archive", sha, "avio"], cwd=REPO, check=True, capture_output=True).stdout
    root.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=root.name + ".", dir=root.parent))
    with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
        tar.extractall(work / "_x", filter="data")
    (work / "_x" / "avio").rename(work / name)
    for path in (work / name).rglob("*.py"):
        stat = path.stat()
        path.write_text(_IMPORT.sub(rf"\1\2 {name}", path.read_text()))
        os.utime(path, (stat.st_atime, stat.st_mtime))  # the archive's mtime: numba's cache key stays put
    try:
        work.rename(root)
    except OSError:  # another process made it first: use theirs
        shutil.rmtree(work, ignore_errors=True)


def load(commit: str) -> ModuleType:
    """The avio package of ``commit``, imported as ``_avio_ref_<sha12>`` (its subpackages:
    ``.filter``, ``.calibration`` ... as in that commit's layout)."""
    sha = _git("rev-parse", f"{commit}^{{commit}}").stdout.decode().strip()
    name = f"_avio_ref_{sha[:12]}"
    root = Path(tempfile.gettempdir()) / name
    if not (root / name / "__init__.py").is_file():
        _extract(sha, root, name)
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module(name)
