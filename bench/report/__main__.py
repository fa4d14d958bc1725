"""``python -m bench.report DIR... [--out OUT]``: the report of one or more sweep folders (bench/report/build.py)."""

from __future__ import annotations

import argparse
import sys

from avio.errors import AvioError
from bench.archive import pack, records_restored
from bench.errors import BenchError
from bench.report.build import build_report
from bench.report.paired import SettingsError


def _rope(text: str | None):
    """``--rope``: a number, or ``PROBLEM=X,...`` as a mapping (values checked by ``check_settings``)."""
    if text is None or "=" not in text:
        return text
    out = {}
    for part in text.split(","):
        name, _, value = part.partition("=")
        if not name.strip():
            raise SettingsError(f"verdict.rope: {part!r} is not PROBLEM=X")
        out[name.strip()] = value.strip()
    return out


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: build the report; 0 on success, 2 with one message on bad input."""
    parser = argparse.ArgumentParser(prog="python -m bench.report",
                                     description="Leaderboard, statistics and figures from run records.")
    parser.add_argument("dirs", nargs="+", help="folders holding job folders (record.json + evals.jsonl)")
    parser.add_argument("--out", default=None, help="output folder (default: FIRST_DIR/report)")
    parser.add_argument("--test", default=None, help="post-hoc test: wilcoxon, nemenyi or conover "
                        "(default: the sweep's verdict.test, else wilcoxon)")
    parser.add_argument("--family", default=None, help="leader (each against the leader) or all (every pair) "
                        "(default: the sweep's verdict.family, else leader)")
    parser.add_argument("--rope", default=None, help="region of practical equivalence in the objective's units: "
                        "a number, or PROBLEM=X,PROBLEM=X (default: the sweep's verdict.rope, else 0)")
    parser.add_argument("--alpha", default=None, help="significance level after Holm, in (0, 1) "
                        "(default: the sweep's verdict.alpha, else 0.05)")
    parser.add_argument("--key", default=None, help="the record field runs are paired on (default: the sweep's "
                        "verdict.key, else instance; records without it are paired on seed)")
    parser.add_argument("--no-tables", action="store_true", help="skip the paper's Tables 1-3 and figures")
    parser.add_argument("--recompute", action="store_true",
                        help="re-run the VIO for the paper's tables even when the stored artifacts match the records")
    parser.add_argument("--pack", action="store_true",
                        help="then archive each folder's records into DIR/records.tar.xz and remove them "
                             "(committed results; the report is rebuilt from the archive)")
    args = parser.parse_args(argv)
    try:
        verdict = {"test": args.test, "family": args.family, "rope": _rope(args.rope), "alpha": args.alpha,
                   "key": args.key}
        with records_restored(args.dirs):  # a folder whose records are archived (bench/archive.py)
            path = build_report(args.dirs, args.out, verdict=verdict, paper_tables=not args.no_tables,
                                recompute=args.recompute)
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
