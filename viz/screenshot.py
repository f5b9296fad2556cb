"""Headless screenshots of an ``.rrd`` in the real rerun viewer (rerun-sdk 0.41).

:func:`screenshot_rrd` starts ``rerun --headless`` on a free local port, opens the recording
through :class:`rerun.experimental.ViewerClient`, moves the time cursor to the end of the
``time`` timeline, and saves a PNG of the whole viewer and of every visible view, together with
what each view reports (warnings, errors). The headless viewer renders with wgpu and needs a
graphics adapter: a GPU driver or a software Vulkan rasterizer (Mesa's lavapipe, Debian/Ubuntu
package ``mesa-vulkan-drivers``). With only software OpenGL (llvmpipe) rerun 0.41 panics with
"Failed to get render context"; :class:`ViewerUnavailable` then carries the viewer's own panic
message, so a test can skip with the precise reason.
"""
from __future__ import annotations

import io
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ViewerUnavailable", "ViewShot", "Screenshots", "screenshot_rrd", "probe_viewer",
           "is_blank", "viewer_executable"]


class ViewerUnavailable(RuntimeError):
    """The headless viewer could not start or render here; ``str(exc)`` says why."""


@dataclass(frozen=True)
class ViewShot:
    """One view of the blueprint: its class, name, origin, what it reported, its screenshot."""

    view_id: str
    view_class: str
    name: str
    origin: str
    visible: bool
    reports: tuple = ()          # ((severity, summary), ...)
    png: Path | None = None
    blank: bool | None = None

    @property
    def errors(self) -> list[str]:
        return [s for sev, s in self.reports if sev == "error"]

    def to_dict(self) -> dict:
        return {"view_id": self.view_id, "view_class": self.view_class, "name": self.name,
                "origin": self.origin, "visible": self.visible,
                "reports": [{"severity": a, "summary": b} for a, b in self.reports],
                "png": None if self.png is None else str(self.png), "blank": self.blank}


@dataclass(frozen=True)
class Screenshots:
    """The screenshots of one recording: the whole viewer and each visible view."""

    rrd: Path
    full: Path
    full_blank: bool
    views: tuple
    viewer_version: str | None = None
    log_errors: tuple = ()       # ERROR lines of the viewer's own log
    timeline: str | None = None
    time_ns: int | None = None
    meta: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"rrd": str(self.rrd), "full": str(self.full), "full_blank": self.full_blank,
                "views": [v.to_dict() for v in self.views], "viewer_version": self.viewer_version,
                "log_errors": list(self.log_errors), "timeline": self.timeline, "time_ns": self.time_ns}


def viewer_executable() -> str | None:
    """The ``rerun`` viewer binary shipped with rerun-sdk (``rerun_cli/rerun``), else the
    ``rerun`` launcher next to this Python (a venv's bin/), else on PATH."""
    name = "rerun.exe" if sys.platform == "win32" else "rerun"
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / name
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    exe = Path(sys.executable).parent / name
    if exe.is_file():
        return str(exe)
    return shutil.which("rerun")


def is_blank(png: bytes | np.ndarray, min_fraction: float = 0.002) -> bool:
    """True when fewer than ``min_fraction`` of the pixels differ (by more than 8/255 in any
    channel) from the image's median colour: an empty or single-colour picture."""
    if isinstance(png, (bytes, bytearray)):
        import matplotlib.image as mpimg

        img = mpimg.imread(io.BytesIO(png), format="png")
    else:
        img = np.asarray(png)
    img = np.asarray(img, dtype=float)
    if img.size == 0:
        return True
    if img.max() > 1.0:
        img = img / 255.0
    rgb = img[..., :3].reshape(-1, 3)
    med = np.median(rgb, axis=0)
    differs = np.any(np.abs(rgb - med) > 8 / 255, axis=1)
    return bool(differs.mean() < min_fraction)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _panic_reason(log_path: Path) -> str:
    try:
        text = log_path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return "no viewer log"
    text = re.sub(r"\x1b\[[0-9;]*m", "", text)
    m = re.search(r"panicked at '([^']*)'", text) or re.search(r"panicked at [^\n]*\n([^\n]+)", text)
    if m:
        return f"the viewer panicked: {m.group(1).strip()}"
    err = [ln for ln in text.splitlines() if "ERROR" in ln]
    return err[-1].strip() if err else (text.strip().splitlines() or ["no output"])[-1]


def _slug(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", s).strip("_")[:40] or "view"


class _Viewer:
    """A headless viewer process and its client; closing kills the process."""

    def __init__(self, log_path: Path, timeout_s: float, executable: str | None = None):
        exe = executable or viewer_executable()
        if exe is None:
            raise ViewerUnavailable("no 'rerun' viewer executable found (pip install rerun-sdk)")
        self.port = _free_port()
        self.log_path = log_path
        env = dict(os.environ, RERUN_APP_ONLY="true")
        self._log = open(log_path, "wb")
        self.proc = subprocess.Popen([exe, "--headless", "--hide-welcome-screen", "--port", str(self.port),
                                      "--memory-limit", "2GB"], stdout=self._log, stderr=subprocess.STDOUT,
                                     env=env, stdin=subprocess.DEVNULL, start_new_session=True)
        from rerun.experimental import ViewerClient

        deadline = time.monotonic() + timeout_s
        self.client = None
        last = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.close()
                raise ViewerUnavailable(_panic_reason(log_path))
            try:
                client = ViewerClient(f"rerun+http://127.0.0.1:{self.port}/proxy")
                client.get_state()
                self.client = client
                break
            except (ConnectionError, RuntimeError, OSError) as exc:
                last = exc
                time.sleep(0.2)
        if self.client is None:
            self.close()
            raise ViewerUnavailable(f"the headless viewer did not answer within {timeout_s:.0f} s ({last})")

    def call(self, fn, *a, **kw):
        """A client call; if the viewer died meanwhile, say why (its panic message)."""
        try:
            return fn(*a, **kw)
        except (ConnectionError, RuntimeError, OSError, TimeoutError) as exc:
            time.sleep(0.3)
            if self.proc.poll() is not None:
                raise ViewerUnavailable(_panic_reason(self.log_path)) from exc
            raise

    def close(self):
        """Stop the viewer and anything it started (its own process group)."""
        proc = self.proc
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                break
            try:
                proc.wait(timeout=10)
                break
            except subprocess.TimeoutExpired:
                continue
        if proc.poll() is None:  # pragma: no cover - killpg failed
            proc.kill()
            proc.wait(timeout=10)
        self._log.close()


def screenshot_rrd(rrd: str | Path, out_dir: str | Path, timeline: str = "time", at: str = "end",
                   max_size: int | None = None, timeout_s: float = 90.0,
                   executable: str | None = None) -> Screenshots:
    """Open ``rrd`` in a headless viewer and save ``viewer.png`` plus ``view-<k>-<name>.png``
    for each visible view into ``out_dir`` (the viewer's log goes to ``viewer.log``).

    ``at``: where the time cursor goes on ``timeline``: ``"end"``, ``"start"`` or ``"middle"``.
    Raises :class:`ViewerUnavailable` when the viewer cannot run here."""
    rrd = Path(rrd).resolve()
    if not rrd.is_file():
        raise FileNotFoundError(rrd)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    viewer = _Viewer(out_dir / "viewer.log", timeout_s, executable)
    try:
        return _shoot(viewer, rrd, out_dir, timeline, at, max_size, timeout_s)
    finally:
        viewer.close()


def _shoot(viewer: _Viewer, rrd: Path, out_dir: Path, timeline: str, at: str, max_size, timeout_s):
    c = viewer.client
    viewer.call(c.open, str(rrd))
    deadline = time.monotonic() + timeout_s
    state = viewer.call(c.get_state)
    while time.monotonic() < deadline:  # poll until loaded (documented protocol)
        state = viewer.call(c.get_state)
        rec = next((r for r in state.recordings if r.store_id == state.active_recording), None)
        if not state.loading and rec is not None and state.views:
            break
        time.sleep(0.25)
    rec = next((r for r in state.recordings if r.store_id == state.active_recording), None)
    t_ns = None
    if rec is not None:
        tl = next((t for t in rec.timelines if t.name == timeline), None)
        if tl is not None and tl.start is not None and tl.end is not None:
            t_ns = {"start": tl.start, "end": tl.end}.get(at, (tl.start + tl.end) // 2)
            viewer.call(c.set_time, timeline, duration=np.timedelta64(int(t_ns), "ns"), play_state="paused")
    # paint until the blueprint has settled (the recording's own blueprint replaces the
    # heuristic one a few frames after the load): the same views twice in a row
    png = viewer.call(c.take_screenshot, max_size=max_size)
    state = viewer.call(c.get_state)
    for _ in range(20):
        png = viewer.call(c.take_screenshot, max_size=max_size)
        again = viewer.call(c.get_state)
        same = [v.view_id for v in again.views] == [v.view_id for v in state.views]
        state = again
        if same:
            break
    full = out_dir / "viewer.png"
    full.write_bytes(png)
    shots = []
    for k, v in enumerate(state.views):  # loop over the blueprint's views (a handful)
        path = None
        blank = None
        if v.visible:
            data = _view_screenshot(viewer, v.view_id, max_size)
            path = out_dir / f"view-{k}-{_slug(v.name or v.view_class)}.png"
            path.write_bytes(data)
            blank = is_blank(data)
        shots.append([v, path, blank])
    state = viewer.call(c.get_state)   # reports as of the last paint
    by_id = {v.view_id: v for v in state.views}
    views = []
    for v, path, blank in shots:
        cur = by_id.get(v.view_id, v)
        views.append(ViewShot(v.view_id, v.view_class, v.name, v.origin, bool(v.visible),
                              tuple((r.severity, r.summary) for r in cur.reports), path, blank))
    logs = viewer.call(c.get_logs)
    log_errors = tuple(f"{e.target}: {e.message}" for e in logs if e.level.upper() == "ERROR")
    return Screenshots(rrd, full, is_blank(png), tuple(views), state.viewer_version, log_errors,
                       timeline if t_ns is not None else None, t_ns)


def _activate_tab(c, view_id: str) -> bool:
    """Make ``view_id`` the active tab of the Tabs container holding it (edits the blueprint)."""
    bp = c.get_blueprint()
    key = f"/view/{view_id}"
    doc = bp.blueprint
    for path, arch in doc.items():
        cont = arch.get("ContainerBlueprint") if isinstance(arch, dict) else None
        if cont and cont.get("container_kind") == "Tabs" and key in cont.get("contents", []):
            if cont.get("active_tab") == key:
                return False
            cont["active_tab"] = key
            c.set_blueprint(doc, of="recording")
            return True
    return False


def _view_screenshot(viewer: _Viewer, view_id: str, max_size) -> bytes:
    """A view's screenshot; a view in an inactive tab is brought to the front first."""
    c = viewer.client
    try:
        return c.take_screenshot(view_id, max_size=max_size)
    except ConnectionError as exc:
        if "not found" not in str(exc).lower() or not viewer.call(_activate_tab, c, view_id):
            if viewer.proc.poll() is not None:
                raise ViewerUnavailable(_panic_reason(viewer.log_path)) from exc
            raise
    viewer.call(c.take_screenshot, max_size=64)   # one paint with the new active tab
    return viewer.call(c.take_screenshot, view_id, max_size=max_size)


def probe_viewer(work_dir: str | Path, timeout_s: float = 60.0) -> str | None:
    """``None`` when the headless viewer can open a recording and screenshot it here, else the
    reason it cannot (for a test's skip message)."""
    import rerun as rr

    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    rrd = work_dir / "probe.rrd"
    rec = rr.RecordingStream("jointlab-probe")
    rec.save(rrd)
    rec.log("points", rr.Points3D(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])), static=True)
    rec.flush()
    rec.disconnect()
    try:
        screenshot_rrd(rrd, work_dir / "probe", timeout_s=timeout_s)
    except ViewerUnavailable as exc:
        return str(exc)
    return None
