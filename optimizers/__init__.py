"""Optimiser plugins behind one batched ask/tell interface (see ``optimizers.base``)."""

from optimizers.base import BestTracker, Optimizer, OptimizerError, check_bounds
from optimizers.registry import available, get, register

__all__ = ["BestTracker", "Optimizer", "OptimizerError", "available", "check_bounds", "get", "register"]
