"""Hydra launchers of avio-bench: Hydra's submitit launchers with packing and non-blocking submission."""
