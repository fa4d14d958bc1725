"""The one base of every error the ``avio`` package raises on purpose.

Callers at the edge (the harness, scripts) catch :class:`AvioError` to turn bad data or bad
input into one clear message; anything else that escapes is a bug and keeps its traceback.
"""

from __future__ import annotations


class AvioError(ValueError):
    """Base of every avio error: bad input or bad data, with a message naming what and where.

    A ``ValueError`` subclass so that code written against the earlier per-module errors, which
    were ``ValueError``s, keeps working.
    """
