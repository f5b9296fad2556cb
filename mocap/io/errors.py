"""User-facing input errors.

Every error a user can cause with a bad file raises :class:`InputError` (or a
subclass). It names the file and, where known, the line, label or key at fault.
The CLI prints ``jointlab: error: <message>`` and exits with status 2 instead of
showing a traceback.
"""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

#: characters no text input holds: C0 controls but tab, newline and carriage return, and DEL
_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
_BREAKS = re.compile(r"[ \t]*[\r\n\x85\u2028\u2029]+[ \t]*")


class InputError(ValueError):
    """Bad user input: a file, a key, a label or a shape that does not fit the contract.

    The message is one line (:func:`one_line`), prefixed with the file and line at fault when
    known; the CLI prints ``jointlab: error: <message>`` and exits with status 2 [1]_. The
    contract is the data format [2]_. A :class:`ValueError`.

    Parameters
    ----------
    message : str
        What is wrong (line breaks become a vertical bar between spaces).
    path : str or pathlib.Path, optional
        The file at fault; kept as :attr:`path`.
    line : int, optional
        Its line, 1-based; kept as :attr:`line`.
    label : str, optional
        The marker label or key at fault, appended to the message unless it already names it;
        kept as :attr:`label`.

    References
    ----------
    .. [1] jointlab inputs (docs/inputs.md).
    .. [2] jointlab data format (docs/format.md).

    Examples
    --------
    >>> str(InputError("no header row", path="m.trc", line=1))
    'm.trc, line 1: no header row'
    """

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
        super().__init__(one_line(where + message))


def one_line(text: str) -> str:
    """``text`` on one line: line breaks (a library's multi-line message, a name holding a
    newline) become a vertical bar between spaces, other control characters their escapes."""
    text = _BREAKS.sub(" | ", str(text).strip())
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], text)


class InputWarning(UserWarning):
    """Something in a user file that the reader tolerated or repaired and the user should know
    (a truncated C3D, a header count that disagrees with the rows). The CLI prints each one as
    one ``jointlab: warning:`` line."""


def warn_input(message: str, path: str | Path | None = None) -> None:
    import warnings

    warnings.warn(InputWarning(f"{path}: {message}" if path is not None else message), stacklevel=3)


def read_text(path: str | Path, encoding: str = "utf-8") -> str:
    """The text of a user file, or an :class:`InputError` naming the file and the line and
    column of the first byte that is not ``encoding`` (a damaged header, a file saved in
    another code page), or the reason it cannot be read (missing, a folder, no permission)."""
    path = Path(path)
    raw = read_bytes(path)
    try:
        return raw.decode(encoding)
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise InputError(f"byte 0x{raw[exc.start]:02x} in column {col} is not {encoding} text",
                         path=path, line=line) from None


def read_bytes(path: str | Path) -> bytes:
    """The bytes of a user file, or an :class:`InputError` saying why it cannot be read."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputError("is a folder, expected a file", path=path) from None
    except PermissionError:
        raise InputError("permission denied (cannot read)", path=path) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path=path) from None


def check_control_chars(text: str, path: str | Path, also: str = "") -> None:
    """Refuse a control character in a text input (a NUL or form feed from a damaged file would
    otherwise end a cell or a line early, silently): an :class:`InputError` naming the line and
    column. ``also``: more characters to refuse (a reader splitting lines on them)."""
    pat = _CONTROL if not also else re.compile(_CONTROL.pattern[:-1] + re.escape(also) + "]")
    m = pat.search(text)
    if m is None:
        return
    i = m.start()
    line = text.count("\n", 0, i) + 1
    col = i - (text.rfind("\n", 0, i) + 1) + 1
    raise InputError(f"control character {text[i]!r} in column {col} (a damaged file?)", path=path,
                     line=line)


class quiet_stderr:
    """Silence file descriptor 2 (a C++ library's own messages) inside the ``with`` block."""

    def __enter__(self):
        try:
            sys.stderr.flush()
            self._saved = os.dup(2)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)
        except OSError:
            self._saved = None
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.dup2(self._saved, 2)
            os.close(self._saved)
        return False
