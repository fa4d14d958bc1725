"""The project's text files hold no control characters but the newline: a LaTeX command written
through a non-raw Python string (``"\\tau"``, ``"\\big"``, ``"\\neq"``) becomes a tab, a backspace
or a newline, and docs/model.md's equations once rendered broken that way (commit f4d82bc)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".sh", ".toml", ".txt"}
SKIP = {".venv", ".git", "node_modules", "site", "__pycache__"}
CONTROL = re.compile(r"[\x00-\x09\x0b-\x1f\x7f]")


def _text_files() -> list[Path]:
    return [p for p in ROOT.rglob("*") if p.suffix in SUFFIXES and p.is_file()
            and not SKIP & set(p.relative_to(ROOT).parts)]


def offenders(paths, root: Path = ROOT) -> list[str]:
    """'path:line: character' for each control character (the newline aside) in the files (split at
    the newline alone: str.splitlines would split at a form feed or a vertical tab and hide it)."""
    out = []
    for path in paths:
        for number, line in enumerate(path.read_text(errors="replace").split("\n"), 1):
            out.extend(f"{path.relative_to(root)}:{number}: {m.group()!r}" for m in CONTROL.finditer(line))
    return out


def test_no_control_characters_in_the_text_files():
    files = _text_files()
    assert len(files) > 100 and ROOT / "docs" / "model.md" in files
    assert offenders(files) == []


def test_latex_commands_turned_into_control_characters_are_found(tmp_path):
    bad = tmp_path / "eq.md"
    bad.write_text("$$ \\tfrac12 \tau_k \\tag{1} $$\nok line\n\\operatorname{tr}\\!\big(S\\big) \frac12\n")
    assert offenders([bad], tmp_path) == ["eq.md:1: '\\t'", "eq.md:3: '\\x08'", "eq.md:3: '\\x0c'"]
