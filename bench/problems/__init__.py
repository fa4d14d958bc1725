"""Registered problems: cheap analytic ones and the VIO calibration objective."""

from bench.problems._make import CallableProblem, make
from bench.problems.base import Problem, ProblemError, available, build_problem, get, register

__all__ = ["CallableProblem", "Problem", "ProblemError", "available", "build_problem", "get", "make", "register"]
