"""The one base of every error the ``avio`` package raises on purpose.

Callers at the edge (the harness, scripts) catch :class:`AvioError` to turn bad data or bad
input into one clear message; anything else that escapes is a bug and keeps its traceback.

:class:`AvioError` derives from ``Exception``, not ``ValueError``: an edge that catches it
catches exactly the errors avio raises on purpose, while a ``ValueError`` from a library or a
bug (numpy, a wrong shape, a float() of a bad string that nobody meant to reach the edge) is not
mistaken for bad input. Code that must catch a library's ``ValueError`` (parsing a number,
reading an ``.npz``) catches it locally, next to the call, and raises an ``AvioError`` naming
the file or the setting.
"""

from __future__ import annotations


class AvioError(Exception):
    """Base of every avio error: bad input or bad data, with a message naming what and where."""
