"""The study's folder lock: one study writes an ``--out`` folder at a time, and a lock whose
owner is gone never blocks a resume.

The lock is an exclusive ``flock`` on ``DIR/.jointlab-study/lock``; its holder writes one line
into it, ``<pid> <host> <start>`` (``start``: the process's start time in clock ticks from
``/proc/<pid>/stat`` where it exists, so that a reused pid is not taken for the owner). A second
study on the same folder waits for the lock, saying so once. ``flock`` belongs to the open file,
so a process that forked from the owner (a pool worker) holds it too: the pool's workers drop
their inherited copy when they start (:func:`drop_inherited`), and they die with the process
that started them (:mod:`ident.study.executor`). Should a lock still be held while the process
named in it is gone (its workers survived an older jointlab, say), the waiting study takes it
over with one line: it moves a fresh lock file of its own in place of the old one (the stale
holders keep the old, unlinked file) under a second short lock (``lock.takeover``), so two
studies that both see the stale lock never both take it. Only a lock written on this host is
judged: another host's pid means nothing here (a study on a shared file system waits).
"""
from __future__ import annotations

import os
from pathlib import Path
import socket
import time

#: the file descriptors of the study locks this process holds (what a forked worker drops)
_HELD: set[int] = set()


def _start_ticks(pid: int) -> str:
    """The process's start time (field 22 of ``/proc/<pid>/stat``) or ``"-"`` where unknown."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
        return raw[raw.rindex(b")") + 2:].split()[19].decode("ascii")
    except (OSError, ValueError, IndexError, UnicodeDecodeError):
        return "-"


def _owner_line() -> str:
    pid = os.getpid()
    return f"{pid} {socket.gethostname()} {_start_ticks(pid)}\n"


def _owner(path: Path):
    """``(pid, host, start)`` read from the lock file, or None when it holds no such line (an
    older jointlab's empty lock file, damage: then nothing is judged and the study waits)."""
    try:
        parts = path.read_bytes()[:200].decode("ascii").split()
        pid = int(parts[0])
        return (pid, parts[1], parts[2]) if pid > 0 and len(parts) == 3 else None
    except (OSError, ValueError, IndexError, UnicodeDecodeError):
        return None


def owner_gone(owner) -> bool:
    """Whether the process named by ``owner`` (:func:`_owner`) is certainly gone: same host, and
    no process of that pid, or one that started at another time (the pid was reused)."""
    if owner is None:
        return False
    pid, host, start = owner
    if host != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:      # alive, another user's
        return False
    except OSError:
        return False
    now = _start_ticks(pid)
    return start != "-" and now != "-" and now != start


def drop_inherited() -> None:
    """In a process forked while this process held study locks: let go of the inherited copies
    (without unlocking: the lock is the parent's). Each descriptor is pointed at ``/dev/null``
    rather than closed, so the file object that owns the number closes a harmless file later."""
    if not _HELD:
        return
    null = os.open(os.devnull, os.O_RDONLY)
    try:
        for fd in list(_HELD):
            try:
                os.dup2(null, fd, inheritable=False)
            except OSError:
                pass
    finally:
        os.close(null)
    _HELD.clear()


class StudyLock:
    """The exclusive lock of a study folder (see the module docstring); ``say`` (one line) is
    told when the study waits or takes over a stale lock; ``poll``: seconds between tries."""

    def __init__(self, path, say=None, poll: float = 0.2):
        self.path, self.say, self.poll, self.fh = Path(path), say, poll, None

    def __enter__(self):
        try:
            import fcntl
        except ImportError:                                 # pragma: no cover (Windows)
            return self
        waited = False
        while True:  # until this process holds the lock on the file now at self.path
            fh = open(self.path, "a+b")
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                fh.close()
                owner = _owner(self.path)
                if owner_gone(owner):
                    fh = self._take_over(fcntl, owner)
                    if fh is not None:
                        break
                    continue
                if not waited and self.say is not None:
                    self.say(f"another command is writing {self.path.parent.parent}; waiting for it")
                waited = True
                time.sleep(self.poll)
                continue
            with self._guard(fcntl):    # a takeover checks the owner line under the same guard
                if self._is_current(fh):
                    self._write_owner(fh)
                    break
            fh.close()                  # a takeover replaced the file meanwhile: try the new one
        self.fh = fh
        _HELD.add(fh.fileno())
        return self

    @staticmethod
    def _write_owner(fh) -> None:
        fh.seek(0)
        fh.truncate()
        fh.write(_owner_line().encode("ascii"))
        fh.flush()

    def _guard(self, fcntl):
        """The short lock under which the owner line is written and a takeover decided."""
        import contextlib

        @contextlib.contextmanager
        def held():
            with open(self.path.with_name(self.path.name + ".takeover"), "a+b") as guard:
                fcntl.flock(guard, fcntl.LOCK_EX)
                yield            # closing the file releases its flock
        return held()

    def _is_current(self, fh) -> bool:
        try:
            st = os.stat(self.path)
        except OSError:
            return False
        return os.fstat(fh.fileno()).st_ino == st.st_ino and os.fstat(fh.fileno()).st_dev == st.st_dev

    def _take_over(self, fcntl, owner):
        """Replace a stale lock file (its owner ``owner`` is gone) by a fresh one held by this
        process; the open, locked file, or None when the lock changed meanwhile (freed, or
        taken over by another study): then the caller tries again."""
        with self._guard(fcntl):
            if _owner(self.path) != owner:          # another study took it over meanwhile
                return None
            try:
                with open(self.path, "rb") as fh:   # freed meanwhile: no takeover needed
                    fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return None
            except BlockingIOError:
                pass
            except OSError:
                return None
            tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.new")
            new = open(tmp, "w+b")
            fcntl.flock(new, fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._write_owner(new)
            os.replace(tmp, self.path)
            if self.say is not None:
                self.say(f"the lock of {self.path.parent.parent} was held for process {owner[0]}, "
                         "which is gone; taking it over")
            return new

    def __exit__(self, *exc):
        if self.fh is not None:
            import fcntl

            _HELD.discard(self.fh.fileno())
            try:
                self.fh.seek(0)
                self.fh.truncate()
            except OSError:
                pass
            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()
            self.fh = None
        return False
