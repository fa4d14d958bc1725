"""Filters in lock-step (issue 30): blocks of 2, 4 or 8 filters whose dense phases run in C, all at once
(:mod:`~avio.filter.lanes.block`: the frame loop; :mod:`~avio.filter.lanes.native`: the C, built on
first use; covariance.c and update.c: the phases). avio/filter/batch.py runs a batch in blocks where the
C is available and numba's per-filter kernel (avio/filter/kernels.py) where it is not, with the same
bits either way."""
