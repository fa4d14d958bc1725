"""Screenshot a report.html in headless Chromium (for results/), and print the page's own check.

    python scripts/screenshot_report.py results/synthetic/report/report.html /tmp/report_screenshot.png [--height 2400]

Needs Debian's ``chromium`` (``apt-get install -y chromium``). Prints how many figures decoded and
which sections are present, as the page's script reports them (``<div id="check">``).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("page", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--width", type=int, default=1400)
    parser.add_argument("--height", type=int, default=2400)
    args = parser.parse_args()
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(chromium).exists():
        print("chromium is absent: apt-get install -y chromium", file=sys.stderr)
        return 2
    if not args.page.is_file():
        print(f"{args.page}: no such file", file=sys.stderr)
        return 2
    uri = args.page.resolve().as_uri()
    with tempfile.TemporaryDirectory() as profile:
        dom = subprocess.run([chromium, *FLAGS, f"--user-data-dir={profile}/a", "--virtual-time-budget=10000",
                              "--dump-dom", uri], capture_output=True, text=True, timeout=180).stdout
        subprocess.run([chromium, *FLAGS, f"--user-data-dir={profile}/b", f"--window-size={args.width},{args.height}",
                        f"--screenshot={args.out.resolve()}", uri], capture_output=True, timeout=180, check=True)
    check = re.search(r'<div id="check"[^>]*>([^<]*)', dom)
    print(check.group(1) if check else "the page's check did not run")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
