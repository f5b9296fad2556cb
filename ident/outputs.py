"""Safe output writing: every file a command writes lies inside ``--out``, is written to a
temporary name and renamed into place, and is registered with its sha256 and the command that
wrote it in the output manifest ``--out/.jointlab-outputs.json``.

Rules (docs/outputs.md):

* a path is resolved (symlinks followed) and must stay inside ``--out``; a path that leaves it
  (``..``, an absolute id, a symlink to an input) is refused with one line;
* ``--out`` is never an input, inside an input folder or a campaign, and never contains a
  campaign (a campaign's parent folder is not an output folder);
* an existing file is overwritten only when the manifest says the same command wrote it; any
  other file (a user's, another command's) is refused with one line naming it;
* a command stages its files in ``--out/.jointlab-tmp/`` and :meth:`OutputDir.commit` moves
  them into place after every check passed, so a failure leaves no partial output.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

from mocap.io.errors import InputError

__all__ = ["OutputDir", "ForeignFileError", "MANIFEST", "STAGE_DIR", "file_sha256", "cap_workers",
           "check_out_dir"]

MANIFEST = ".jointlab-outputs.json"
LOCK = ".jointlab-outputs.lock"
STAGE_DIR = ".jointlab-tmp"
#: names inside --out that belong to the bookkeeping, never to a command's outputs
INTERNAL = (MANIFEST, LOCK, STAGE_DIR, ".jointlab-study", ".jointlab-study.json")


class ForeignFileError(InputError):
    """An output path holds a file this command did not write."""


def file_sha256(path, chunk: int = 1 << 20) -> str:
    """sha256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            b = fh.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def cap_workers(n: int | None, option: str = "--workers") -> int | None:
    """``n`` capped at the CPUs this process may use, with a one-line note when capped."""
    if n is None:
        return None
    if n < 1:
        raise InputError(f"{option} must be >= 1, got {n}")
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    if n > cpus:
        print(f"jointlab: note: {option} {n} capped at the {cpus} CPU(s) of this machine", file=sys.stderr)
        return cpus
    return n


def _campaign_root(path: Path) -> Path | None:
    for folder in ((path, *path.parents) if path.is_dir() else path.parents):
        if (folder / "campaign.toml").is_file():
            return folder
    return None


def _regions(inputs) -> list[Path]:
    """What the inputs protect: an input folder (or a file's folder) and its campaign folder."""
    regions = []
    for inp in inputs:
        if inp is None:
            continue
        p = Path(inp)
        if not p.exists():
            continue
        p = p.resolve()
        regions.append(p if p.is_dir() else p.parent)
        root = _campaign_root(p)
        if root is not None:
            regions.append(root)
    return list(dict.fromkeys(regions))


def check_out_dir(out, inputs=(), flag: str = "--out", contain: bool = True) -> Path:
    """Resolve ``out`` and refuse one that is an input folder, lies inside one (or inside an
    input's campaign), or (``contain``) contains one. Creates the folder."""
    out = Path(out).resolve()
    for region in _regions(inputs):
        if out == region or region in out.parents:
            raise InputError(f"{flag} {out} is inside the input folder {region}; choose another folder",
                             path=out)
        if contain and out in region.parents:
            raise InputError(f"{flag} {out} contains the input folder {region}; nothing is written "
                             "around an input, choose another folder", path=out)
    out.mkdir(parents=True, exist_ok=True)
    return out


class FolderLock:
    """An exclusive ``flock`` on a lock file of an output folder (a no-op where flock does not
    exist): a second command on the same folder waits for the first (``say`` tells the user it
    waits), then finds its outputs."""

    def __init__(self, path: Path, say=None):
        self.path, self.say, self.fh = path, say, None

    def __enter__(self):
        try:
            import fcntl
        except ImportError:                                 # pragma: no cover (Windows)
            return self
        self.fh = open(self.path, "a+")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if self.say is not None:
                self.say(f"another command is writing {self.path.parent}; waiting for it")
            fcntl.flock(self.fh, fcntl.LOCK_EX)
        return self

    def __exit__(self, *exc):
        if self.fh is not None:
            import fcntl

            fcntl.flock(self.fh, fcntl.LOCK_UN)
            self.fh.close()
        return False


class OutputDir:
    """The output folder of one command run.

    ``out``: the ``--out`` folder; ``command``: the name the manifest records as the writer;
    ``inputs``: paths whose folders (and campaigns) ``out`` must stay clear of. Paths given to
    the methods are relative to ``out`` (``"angles/t1.csv"``) or absolute inside it."""

    def __init__(self, out, command: str, inputs=(), flag: str = "--out"):
        self.root = check_out_dir(out, inputs, flag)
        self.command = command
        self._stages: list[Path] = []

    # paths ---------------------------------------------------------------------------------
    def rel(self, path) -> str:
        """``path`` as a '/'-separated path relative to ``out``, after resolving every symlink
        on the way; refuses a path that leaves ``out`` or names the bookkeeping files."""
        p = Path(path)
        full = p if p.is_absolute() else self.root / p
        parent = full.parent.resolve()
        final = parent / full.name
        if final.is_symlink():
            final = final.resolve()
        if final == self.root or self.root not in final.parents:
            raise InputError(f"this output path leaves the output folder {self.root} (through "
                             "'..', an absolute name or a symlink); refusing to write it", path=full)
        rel = final.relative_to(self.root).as_posix()
        if rel.split("/", 1)[0] in INTERNAL:
            raise InputError("this output path is reserved for jointlab's bookkeeping", path=full)
        return rel

    def path(self, rel_or_abs) -> Path:
        """The checked absolute path of an output (see :meth:`rel`)."""
        return self.root / self.rel(rel_or_abs)

    # the manifest ----------------------------------------------------------------------------
    def _lock(self):
        return FolderLock(self.root / LOCK)

    def _load(self) -> dict:
        try:
            doc = json.loads((self.root / MANIFEST).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}
        files = doc.get("files") if isinstance(doc, dict) else None
        return {k: v for k, v in files.items() if isinstance(v, dict)} if isinstance(files, dict) else {}

    def _save(self, files: dict) -> None:
        data = json.dumps({"format": 1, "files": dict(sorted(files.items()))}, indent=1)
        write_atomic(self.root / MANIFEST, data, self.root / STAGE_DIR)

    def entries(self) -> dict:
        """rel path -> {"sha256", "command"} of every registered output."""
        return self._load()

    def owner(self, rel: str) -> str | None:
        e = self._load().get(rel)
        return None if e is None else e.get("command")

    def recorded_sha(self, rel: str) -> str | None:
        e = self._load().get(rel)
        return None if e is None else e.get("sha256")

    def is_own(self, rel: str, files: dict | None = None) -> bool:
        files = self._load() if files is None else files
        e = files.get(rel)
        return e is not None and e.get("command") == self.command

    def check(self, rels, files: dict | None = None) -> None:
        """Refuse (one line naming the file) when one of ``rels`` exists and was not written by
        this command."""
        files = self._load() if files is None else files
        for rel in rels:
            p = self.root / rel
            if not (p.exists() or p.is_symlink()):
                continue
            if p.is_dir() and not p.is_symlink():
                raise ForeignFileError(f"{p} is a folder where `jointlab {self.command}` writes a file; "
                                       "move it away or choose another --out", path=p)
            if self.is_own(rel, files):
                continue
            who = files.get(rel, {}).get("command")
            by = f"`jointlab {who}`" if who else "someone else (it is not in the output manifest)"
            raise ForeignFileError(f"{p} was written by {by}, not by `jointlab {self.command}`; "
                                   "refusing to overwrite it: move it away or choose another --out",
                                   path=p)

    def register(self, shas: dict, forget=()) -> None:
        """Record ``{rel: sha256 or None}`` as this command's (None: being written now) and drop
        ``forget`` from the manifest."""
        with self._lock():
            files = self._load()
            for rel, sha in shas.items():
                files[rel] = {"sha256": sha, "command": self.command}
            for rel in forget:
                files.pop(rel, None)
            self._save(files)

    def claim(self, rels) -> None:
        """Check then register ``rels`` as being written by this command (for files written by
        worker processes: registered first, so an interrupted run still owns them)."""
        rels = list(rels)
        with self._lock():
            files = self._load()
            self.check(rels, files)
            changed = False
            for rel in rels:
                if not self.is_own(rel, files):
                    files[rel] = {"sha256": None, "command": self.command}
                    changed = True
            if changed:
                self._save(files)

    def matches(self, rel: str, sha: str | None = None) -> bool:
        """The file exists, is this command's, and its bytes hash to ``sha`` (default: the
        manifest's record)."""
        p = self.root / rel
        if not p.is_file():
            return False
        files = self._load()
        if not self.is_own(rel, files):
            return False
        want = sha if sha is not None else files[rel].get("sha256")
        return want is not None and file_sha256(p) == want

    # writing ---------------------------------------------------------------------------------
    def tmp_dir(self) -> Path:
        d = self.root / STAGE_DIR
        d.mkdir(parents=True, exist_ok=True)
        return d

    def stage(self) -> Path:
        """A fresh, empty staging folder inside ``out`` (same file system): write there, then
        :meth:`commit` it."""
        d = self.tmp_dir() / f"{self.command}-{os.getpid()}-{time.monotonic_ns()}"
        d.mkdir(parents=True)
        self._stages.append(d)
        return d

    def final(self, path) -> Path:
        """Where a file written into one of this run's staging folders ends up under ``out``."""
        p = Path(path)
        for st in self._stages:
            if p == st or st in p.parents:
                return self.root / p.relative_to(st)
        return p

    def check_early(self, rels) -> None:
        """Refuse before any work when a known output name holds a file this command did not
        write (:meth:`commit` checks every file again)."""
        self.check([self.rel(r) for r in rels])

    def write(self, rel, data: bytes | str) -> Path:
        """Write one output atomically (temporary name, then rename) and register it."""
        rel = self.rel(rel)
        with self._lock():
            files = self._load()
            self.check([rel], files)
            final = self.root / rel
            final.parent.mkdir(parents=True, exist_ok=True)
            tmp = write_atomic(self.tmp_dir() / f"w-{os.getpid()}-{time.monotonic_ns()}.tmp", data, None)
            files[rel] = {"sha256": file_sha256(tmp), "command": self.command}
            self._save(files)
            os.replace(tmp, final)
        return final

    def install(self, src, rel) -> Path:
        """Move the finished file ``src`` (inside ``out``'s file system) to ``rel``."""
        return self.install_many({self.rel(rel): Path(src)})[0]

    def commit(self, staging: Path, dest: str = "", prune: bool = False) -> list[Path]:
        """Move every file under ``staging`` to the same relative place under ``out/dest``
        (after checking that none of them overwrites a file this command did not write), and
        remove ``staging``. ``prune``: also delete this command's registered files under
        ``dest`` that the new set no longer holds (never anything unregistered)."""
        staging = Path(staging)
        moves = {}
        for src in sorted(p for p in staging.rglob("*") if p.is_file() or p.is_symlink()):
            if src.is_symlink():
                raise InputError(f"refusing to install the symlink {src}", path=src)
            relsrc = src.relative_to(staging).as_posix()
            moves[self.rel(f"{dest}/{relsrc}" if dest else relsrc)] = src
        prefix = self.rel(dest) + "/" if dest else None
        written = self.install_many(moves, prune_prefix=prefix if prune else None)
        shutil.rmtree(staging, ignore_errors=True)
        if staging in self._stages:
            self._stages.remove(staging)
        return written

    def install_many(self, moves: dict, prune_prefix: str | None = None) -> list[Path]:
        """``{rel: finished file}``: check all, register all, then rename each into place."""
        with self._lock():
            files = self._load()
            self.check(list(moves), files)
            shas = {rel: file_sha256(src) for rel, src in moves.items()}
            stale = []
            if prune_prefix is not None:
                stale = [r for r, e in files.items() if r.startswith(prune_prefix) and r not in moves
                         and e.get("command") == self.command]
            for rel, sha in shas.items():
                files[rel] = {"sha256": sha, "command": self.command}
            for rel in stale:
                files.pop(rel, None)
            self._save(files)
            out = []
            for rel, src in moves.items():
                final = self.root / rel
                final.parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, final)
                out.append(final)
            for rel in stale:
                p = self.root / rel
                if p.is_file() and not p.is_symlink():
                    p.unlink()
        return out

    def discard(self) -> None:
        """Remove this run's staging folders (nothing outside them is touched)."""
        for d in self._stages:
            shutil.rmtree(d, ignore_errors=True)
        self._stages.clear()
        try:
            (self.root / STAGE_DIR).rmdir()
        except OSError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.discard()
        return False


def write_atomic(path, data: bytes | str, tmp_dir) -> Path:
    """Write ``data`` to a temporary name in ``tmp_dir`` (same file system; None: the final
    name itself is already temporary), then rename it to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if tmp_dir is None:
        tmp = path
    else:
        Path(tmp_dir).mkdir(parents=True, exist_ok=True)
        tmp = Path(tmp_dir) / f"{path.name}.{os.getpid()}.{time.monotonic_ns()}.tmp"
    try:
        with open(tmp, "wb") as fh:
            fh.write(data.encode("utf-8") if isinstance(data, str) else data)
        if tmp != path:
            os.replace(tmp, path)
    except BaseException:
        if tmp != path:
            tmp.unlink(missing_ok=True)
        else:
            path.unlink(missing_ok=True)
        raise
    return path
