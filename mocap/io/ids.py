"""Trial ids (FORMAT.md): data, never paths or code."""
from __future__ import annotations

import re
from pathlib import Path

from mocap.io.errors import InputError

#: FORMAT.md: a trial id is letters, digits, '.', '_' and '-', at most 100 characters, and does
#: not start with '.' (a tool may use it in a file name)
TRIAL_ID = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}")


def check_trial_id(tid, what: str, path: Path | None = None) -> str:
    """``tid`` as text when it is a FORMAT.md trial id (a TOML integer counts as its digits),
    else an :class:`InputError` naming ``what`` (``--trial`` or the manifest's trial)."""
    if isinstance(tid, bool) or not isinstance(tid, (str, int)):
        raise InputError(f"{what}: a trial id must be text, got {type(tid).__name__} {tid!r}",
                         path=path, label="id")
    text = str(tid)
    if TRIAL_ID.fullmatch(text) is None:
        shown = repr(text if len(text) <= 40 else text[:40] + "...")
        raise InputError(f"{what}: trial id {shown} ({len(text)} characters) is not made of letters, "
                         "digits, '.', '_' and '-' (at most 100 characters, not starting with '.')",
                         path=path, label="id")
    return text
