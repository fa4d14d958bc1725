"""Issue 30's "default job", the one command line the benchmarks time: ``python -m bench`` with these overrides
(psoga, 500 evaluations on the synthetic problem, no report)."""

DEFAULT_JOB = ("optimizer=psoga", "instance=0", "budget.evals=500", "report=false")
