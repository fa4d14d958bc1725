"""``python -m bench.report.paper RUNS_DIR... --out DIR``: the paper's Tables 1–3 and figures alone
(:mod:`bench.report.paper.tables`; ``python -m bench.report`` builds them too, inside the report).
It succeeds ``python -m bench.tables`` of the layout before the package move."""

from bench.report.paper.tables import main

if __name__ == "__main__":
    raise SystemExit(main())
