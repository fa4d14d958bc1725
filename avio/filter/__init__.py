"""The batched sliding-window trifocal VIO: n error-state Kalman filters, one per candidate
calibration, over the same drive (the model: docs/model.md).

- :mod:`~avio.filter.config`: settings and results; :mod:`~avio.filter.prepare`: the
  calibration-free inputs, once per sequence; :mod:`~avio.filter.batch`: :func:`run`, threads.
- The compiled kernels: :mod:`~avio.filter.lanes` (blocks of filters in lock-step, their dense
  phases in C), :mod:`~avio.filter.kernels` (the run of a range of filters, one after the other),
  :mod:`~avio.filter.update` (the trifocal update), :mod:`~avio.filter.measurement` (residuals
  and Jacobians), :mod:`~avio.filter.outliers` (RANSAC, gate, innovations),
  :mod:`~avio.filter.propagation` (IMU preintegration and propagation), ``_linalg`` (small
  dense algebra).
"""

from avio.filter.batch import default_threads, run, set_threads, threads
from avio.filter.config import DECISION_SOURCES, OUTLIER_MODES, FilterConfig, FilterError, FilterResult
from avio.filter.prepare import imu_still, prepare

__all__ = ["DECISION_SOURCES", "OUTLIER_MODES", "FilterConfig", "FilterError", "FilterResult", "default_threads",
           "imu_still", "prepare", "run", "set_threads", "threads"]
