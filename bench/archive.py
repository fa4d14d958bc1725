"""A sweep folder's records in one compressed file, and the report rebuilt from it.

Committed results keep in git only what a reader looks at (the report's text, tables and a few
figures) and, per results set, one archive ``records.tar.xz`` of everything else the sweep wrote:
job folders (``evals.jsonl``, ``job.json``, ``record.json``, Hydra's ``.hydra/`` and log),
``multirun.yaml`` and the paper tables' ``artifacts/`` (docs/guide/records-and-report.md, "Committed
results"). ``python -m bench.report DIR`` on such a folder restores the files into ``DIR`` for the
build, and removes them after it, so the report is rebuilt from what is committed, byte for byte
(tested), and the working tree is left as it was.

The archive is deterministic (the same files give the same bytes): members sorted by name, owners,
permissions and times fixed, so re-packing unchanged records changes nothing in git. tar + xz from
the standard library (``tarfile``, ``lzma``): no columnar format keeps the logs' exact text, which the
byte-identical rebuild needs.
"""

from __future__ import annotations

import contextlib
import fnmatch
import io
import json
import lzma
import tarfile
from collections.abc import Iterator
from pathlib import Path

from bench.errors import BenchError

ARCHIVE = "records.tar.xz"
#: Left out of the archive: what the report makes, and the locks of running processes.
EXCLUDED_TOP = frozenset({"report", ARCHIVE})
EXCLUDED_NAMES = frozenset({".lock"})


class ArchiveError(BenchError):
    """A records archive that cannot be written or read back (names the file)."""


#: The evaluation logs: what a study that reads only its runs' best points may leave out (``logs=False``).
LOG_NAME = "evals.jsonl"


def _members(sweep_dir: Path, logs: bool = True) -> list[Path]:
    """Files under ``sweep_dir`` that go into the archive, sorted (relative paths); without ``logs``,
    the evaluation logs stay out."""
    files = []
    for path in sweep_dir.rglob("*"):
        rel = path.relative_to(sweep_dir)
        if rel.parts[0] in EXCLUDED_TOP or path.name in EXCLUDED_NAMES or path.is_dir():
            continue
        if not logs and path.name == LOG_NAME:
            continue
        if path.is_symlink():
            raise ArchiveError(f"{path} is a symbolic link; records are archived as files only")
        files.append(rel)
    return sorted(files, key=lambda p: p.as_posix())


def pack(sweep_dir: str | Path, remove: bool = False, logs: bool = True) -> Path:
    """Write ``sweep_dir/records.tar.xz`` (every file but ``report/``); with ``remove``, delete the
    archived files afterwards (emptied folders too). Without ``logs`` the evaluation logs are left
    out of the archive (and deleted with ``remove``): for a study whose summary reads only the runs'
    records, not a sweep whose report is rebuilt from the archive. Returns the archive's path."""
    sweep_dir = Path(sweep_dir)
    members = _members(sweep_dir, logs)
    if not members:
        raise ArchiveError(f"{sweep_dir}: nothing to archive (no records)")
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        for rel in members:
            data = (sweep_dir / rel).read_bytes()
            info = tarfile.TarInfo(rel.as_posix())
            info.size, info.mtime, info.mode = len(data), 0, 0o644
            info.uid = info.gid = 0
            info.uname = info.gname = ""
            tar.addfile(info, io.BytesIO(data))
    archive = sweep_dir / ARCHIVE
    archive.write_bytes(lzma.compress(buffer.getvalue(), preset=9 | lzma.PRESET_EXTREME))
    if remove:
        left_out = sorted(set(_members(sweep_dir)) - set(members))
        _remove(sweep_dir, members + left_out, locks=True)
    return archive


def _remove(sweep_dir: Path, members: list[Path], locks: bool = False) -> None:
    """Delete the archived files and the folders they leave empty (with ``locks``, the finished
    sweep's lock files too: they name a past holder, not a result)."""
    for rel in members:
        (sweep_dir / rel).unlink()
    folders = sorted({p for rel in members for p in rel.parents}, key=lambda p: len(p.parts), reverse=True)
    for folder in folders:
        if locks:
            (sweep_dir / folder / ".lock").unlink(missing_ok=True)
        if folder != Path("."):
            with contextlib.suppress(OSError):  # not empty: something of the user's is kept
                (sweep_dir / folder).rmdir()


def _extract(archive: Path, into: Path) -> list[Path]:
    """Restore the archive's files into ``into``; refuses to overwrite a file. Returns them (relative)."""
    try:
        with tarfile.open(archive, mode="r:xz") as tar:
            members = tar.getmembers()
            for m in members:
                if not m.isfile():
                    raise ArchiveError(f"{archive}: member {m.name} is not a plain file")
                if (into / m.name).exists():
                    raise ArchiveError(f"{archive}: {into / m.name} exists; a folder holds either its records or "
                                       "their archive, not both")
            tar.extractall(into, members=members, filter="data")  # the data filter refuses ../ and links
    except (tarfile.TarError, lzma.LZMAError, EOFError) as err:
        raise ArchiveError(f"{archive}: unreadable archive ({err})") from None
    return [Path(m.name) for m in members]


def unpack(sweep_dir: str | Path) -> list[Path]:
    """The inverse of ``pack(sweep_dir, remove=True)``: restore the archive's files into the folder
    and delete the archive (for a sweep that will add jobs and be packed again). Refuses to
    overwrite a file. Returns the restored files (relative)."""
    sweep_dir = Path(sweep_dir)
    archive = sweep_dir / ARCHIVE
    if not archive.is_file():
        raise ArchiveError(f"{archive}: no archive to unpack")
    members = _extract(archive, sweep_dir)
    archive.unlink()
    return members


def has_records(sweep_dir: Path) -> bool:
    return any(p.name == "record.json" for p in Path(sweep_dir).rglob("record.json")
               if "report" not in p.relative_to(sweep_dir).parts[:1])


@contextlib.contextmanager
def records_restored(dirs: list[str | Path]) -> Iterator[None]:
    """While the block runs, each folder of ``dirs`` that holds an archive and no records holds its
    records again; they are removed afterwards (whatever the block did)."""
    restored: list[tuple[Path, list[Path]]] = []
    try:
        for d in map(Path, dirs):
            archive = d / ARCHIVE
            if archive.is_file() and not has_records(d):
                restored.append((d, _extract(archive, d)))
        yield
    finally:
        for d, members in restored:
            _remove(d, members)


def job_records(sweep_dir: str | Path, pattern: str = "*/*/*/record.json") -> list[tuple[Path, dict]]:
    """Every job record of a sweep folder matching ``pattern`` (relative to the folder, glob syntax):
    ``(relative path, record)`` sorted by path, read from the files, or from ``records.tar.xz`` when
    the folder holds only the archive (read in memory, nothing written). For the studies' scripts,
    which read best points, not the logs."""
    sweep_dir = Path(sweep_dir)
    if has_records(sweep_dir):
        return [(p.relative_to(sweep_dir), json.loads(p.read_text())) for p in sorted(sweep_dir.glob(pattern))]
    archive = sweep_dir / ARCHIVE
    if not archive.is_file():
        return []
    found = []
    try:
        with tarfile.open(archive, mode="r:xz") as tar:
            for member in tar:
                if member.isfile() and fnmatch.fnmatchcase(member.name, pattern):
                    found.append((Path(member.name), json.loads(tar.extractfile(member).read())))
    except (tarfile.TarError, lzma.LZMAError, EOFError) as err:
        raise ArchiveError(f"{archive}: unreadable archive ({err})") from None
    return sorted(found, key=lambda item: item[0].as_posix())
