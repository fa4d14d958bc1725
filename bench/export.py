"""``python -m bench.export JOB_DIR ...``: a job's trajectories for evo and other tools.

The documented command; the code lives in :mod:`bench.report.export`."""

from bench.report.export import main

if __name__ == "__main__":
    raise SystemExit(main())
