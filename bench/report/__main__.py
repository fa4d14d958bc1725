"""``python -m bench.report DIR... [--out OUT]``: the report of one or more sweep folders (bench/report/build.py)."""

from __future__ import annotations

import argparse
import sys

from avio.errors import AvioError
from bench.archive import pack, records_restored
from bench.errors import BenchError
from bench.report.build import build_report


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: build the report; 0 on success, 2 with one message on bad input."""
    parser = argparse.ArgumentParser(prog="python -m bench.report",
                                     description="Leaderboard, statistics and figures from run records.")
    parser.add_argument("dirs", nargs="+", help="folders holding job folders (record.json + evals.jsonl)")
    parser.add_argument("--out", default=None, help="output folder (default: FIRST_DIR/report)")
    parser.add_argument("--pairing", choices=("none", "seed"), default="none",
                        help="'seed': Wilcoxon signed-rank on seed-matched runs (default: Mann–Whitney U)")
    parser.add_argument("--alpha", default="0.05", help="significance level after Holm, in (0, 1) (default 0.05)")
    parser.add_argument("--no-tables", action="store_true", help="skip the paper's Tables 1-3 and figures")
    parser.add_argument("--recompute", action="store_true",
                        help="re-run the VIO for the paper's tables even when the stored artifacts match the records")
    parser.add_argument("--pack", action="store_true",
                        help="then archive each folder's records into DIR/records.tar.xz and remove them "
                             "(committed results; the report is rebuilt from the archive)")
    args = parser.parse_args(argv)
    try:
        with records_restored(args.dirs):  # a folder whose records are archived (bench/archive.py)
            path = build_report(args.dirs, args.out, pairing=args.pairing, alpha=args.alpha,
                                paper_tables=not args.no_tables, recompute=args.recompute)
        for folder in args.dirs if args.pack else ():
            print(pack(folder, remove=True))
    except (BenchError, AvioError) as err:  # ReportError, RecordError, StatsError, ...; anything else is a bug
        print(f"bench.report: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"bench.report: error: {err.filename or ''}: {err.strerror}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
