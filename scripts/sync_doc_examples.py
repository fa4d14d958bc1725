"""Copy the shipped files the guides show verbatim into their code blocks (tests check they match).

    python scripts/sync_doc_examples.py          # rewrite the blocks
    python scripts/sync_doc_examples.py --check  # exit 1 naming the stale blocks, change nothing

A block is the fenced block of the page whose first line equals the file's first line.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# page -> the files it shows verbatim
EXAMPLES = {
    "docs/guide/adding-an-optimiser.md": ["optimizers/one_plus_one.py", "bench/conf/optimizer/one_plus_one.yaml"],
    "docs/guide/adding-a-problem.md": ["bench/problems/euroc.py", "bench/conf/problem/euroc.yaml",
                                       "tests/bench/problems/test_euroc_problem.py"],
}


def sync(page: Path, files: list[Path]) -> tuple[str, list[str]]:
    """The page with each file's block replaced by the file, and the files whose block was stale."""
    text, stale = page.read_text(), []
    for path in files:
        content = path.read_text()
        first = content.split("\n", 1)[0]
        pattern = re.compile(r"^(```\w*\n)(" + re.escape(first) + r"\n.*?)^```$", re.S | re.M)
        match = pattern.search(text)
        if match is None:
            raise SystemExit(f"{page}: no code block starts with the first line of {path}")
        if match.group(2) != content:
            stale.append(str(path.relative_to(ROOT)))
            text = text[:match.start(2)] + content + text[match.end(2):]
    return text, stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report stale blocks (exit 1)")
    args = parser.parse_args(argv)
    stale_all = []
    for page, files in EXAMPLES.items():
        text, stale = sync(ROOT / page, [ROOT / f for f in files])
        stale_all += [f"{page}: {f}" for f in stale]
        if stale and not args.check:
            (ROOT / page).write_text(text)
    for line in stale_all:
        print(("stale " if args.check else "synced ") + line, file=sys.stderr)
    return 1 if stale_all and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
