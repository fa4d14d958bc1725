"""Write the settings tables of docs/reference/ from the shipped yaml files (keys, defaults, and
the comments beside them), so the reference is generated from what the code reads.

    python scripts/make_reference.py          # rewrite the generated sections
    python scripts/make_reference.py --check  # exit 1 naming stale pages, change nothing

The generated part of a page lies between ``<!-- generated: ... -->`` and ``<!-- end generated -->``.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "bench" / "conf"
PAGES = {"docs/reference/problems.md": "problem", "docs/reference/optimizers.md": "optimizer"}
BEGIN, END = "<!-- generated: scripts/make_reference.py; edit the yaml files, then run it -->", "<!-- end generated -->"


def _comments(text: str) -> dict[str, str]:
    """{top-level key of ``params``: its comment}, continuation lines (comment-only, deeper) joined."""
    out, key = {}, None
    for line in text.splitlines():
        m = re.match(r"^  ([A-Za-z_]\w*):[^#]*?(?:#\s*(.*))?$", line)
        if m:
            key = m.group(1)
            out[key] = (m.group(2) or "").strip()
        elif key and re.match(r"^\s{3,}#", line):
            out[key] = (out[key] + " " + line.split("#", 1)[1].strip()).strip()
        elif not line.startswith("    "):
            key = None if not line.startswith("  ") else key
    return out


def _value(value) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=10**6).strip()
    return text[:-4].strip() if text.endswith("\n...") else text.replace("\n...", "")


def section(group: str) -> str:
    """Markdown: one table of settings per yaml of ``bench/conf/<group>/``."""
    parts = [BEGIN, ""]
    for path in sorted((CONF / group).glob("*.yaml")):
        text = path.read_text()
        config = yaml.safe_load(text)
        intro = " ".join(line[1:].strip() for line in text.splitlines() if line.startswith("#")).strip()
        parts += [f"### `{config['name']}`", "", intro + f" (`bench/conf/{group}/{path.name}`)", ""]
        params = config.get("params") or {}
        if not params:
            parts += ["No settings.", ""]
            continue
        notes = _comments(text)
        parts += [f"| `{group}.params.` | default | meaning |", "|---|---|---|"]
        for key, value in params.items():
            note = notes.get(key, "").replace("|", "\\|")
            parts.append(f"| `{key}` | `{_value(value)}` | {note} |")
        parts.append("")
    parts.append(END)
    return "\n".join(parts)


def render(page: Path, group: str) -> str:
    text = page.read_text()
    new = section(group)
    if BEGIN in text:
        return re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: new, text, flags=re.S)
    return text.rstrip("\n") + "\n\n## Settings\n\n" + new + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report stale pages (exit 1)")
    args = parser.parse_args(argv)
    stale = []
    for rel, group in PAGES.items():
        page = ROOT / rel
        text = render(page, group)
        if text != page.read_text():
            stale.append(rel)
            if not args.check:
                page.write_text(text)
    for rel in stale:
        print(("stale " if args.check else "wrote ") + rel, file=sys.stderr)
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
