"""Registered problems: cheap analytic ones and the VIO calibration objective."""

from bench.problems.base import Problem, ProblemError, available, get, register

__all__ = ["Problem", "ProblemError", "available", "get", "register"]
