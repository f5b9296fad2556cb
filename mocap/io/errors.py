"""User-facing input errors.

Every error a user can cause with a bad file raises :class:`InputError` (or a
subclass). It names the file and, where known, the line, label or key at fault.
The CLI prints ``jointlab: error: <message>`` and exits with status 2 instead of
showing a traceback.
"""
from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad user input: a file, a key, a label or a shape that does not fit the contract."""

    def __init__(self, message: str, *, path: str | Path | None = None,
                 line: int | None = None, label: str | None = None):
        self.path = None if path is None else Path(path)
        self.line = line
        self.label = label
        where = ""
        if path is not None:
            where = str(path)
            if line is not None:
                where += f", line {line}"
            where += ": "
        if label is not None and label not in message:
            message = f"{message} (marker/key {label!r})"
        super().__init__(where + message)
