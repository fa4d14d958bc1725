"""Hydra configs (a package so that Hydra finds them as ``pkg://bench.conf`` in an installed wheel)."""
