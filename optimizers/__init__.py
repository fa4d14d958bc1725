"""Optimiser plugins behind one batched ask/tell interface (``optimizers.base.AskTell`` owns the contract)."""

from optimizers.base import AskTell, BestTracker, Optimizer, OptimizerError, check_bounds
from optimizers.registry import available, get, register

__all__ = ["AskTell", "BestTracker", "Optimizer", "OptimizerError", "available", "check_bounds", "get", "register"]
