"""Registered problems: cheap analytic ones and the VIO calibration objective."""

from bench.problems.base import Problem, ProblemError, available, build_problem, get, register

__all__ = ["Problem", "ProblemError", "available", "build_problem", "get", "register"]
