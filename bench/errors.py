"""The one base of every error the ``bench`` harness raises on purpose.

Every error class of ``bench`` (``ProblemError``, ``SpaceError``, ``RunError``, ``ConfigError``,
``RecordError``, ``ReportError``, ...) derives from :class:`BenchError`, keeping its own name and
module. The command-line entries (``python -m bench``, ``python -m bench.report``,
``bench.export``, ``bench.report.paper``) catch ``BenchError`` -- with ``avio.errors.AvioError`` and
``optimizers.OptimizerError`` where errors of those packages can arrive -- and print one message;
anything else that escapes is a bug and keeps its traceback.

:class:`BenchError` derives from ``Exception``, not ``ValueError`` (nor ``RuntimeError``, which
``RunError`` and ``LockError`` were): catching it at an edge catches exactly the harness's own
errors, never a ``ValueError`` from a library or a plugin's bug. Code that must catch a library's
``ValueError`` (``float()`` of a config value, pandas or numpy reading a file) catches it
locally and raises a ``BenchError`` naming the setting or the file.
"""

from __future__ import annotations


class BenchError(Exception):
    """Base of every bench error: a bad config, bad records or a job that cannot run as asked;
    the message names what and where."""
