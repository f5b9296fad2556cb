"""The rerun implementation of :class:`viz.sink.Sink` (rerun-sdk 0.41).

Everything that changes over time goes through ``send_columns`` (one call per entity, no Python
loop over frames); static content goes through ``log(..., static=True)``. Each sink owns a
dedicated :class:`rerun.RecordingStream` (never the global one), so several sinks can coexist in
one process. The timeline is ``"time"``: durations in seconds.

Frames: an entity's :meth:`transform` / :meth:`transforms_over_time` maps the entity's points
into its parent's frame (``p_parent = T_parent_entity @ p_entity``), as rerun's ``Transform3D``.
"""
from __future__ import annotations

import logging
import sys
import uuid
from pathlib import Path

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from viz.sink import Sink
from viz.blueprint import default_blueprint

_STRICT = True  # raise on non-loggable data instead of warning (our bug, surface it)


def _entity_part(name: str) -> str:
    """A display name as one entity-path part: characters rerun would need escaped become '_'."""
    import re

    return re.sub(r"[^A-Za-z0-9_.\-]+", "_", str(name).strip("/")).strip("_") or "_"


def _join(path: str, child: str) -> str:
    return path.rstrip("/") + "/" + _entity_part(child)


def _check_time(time, n: int, what: str) -> np.ndarray:
    t = np.asarray(time, dtype=float)
    if t.ndim != 1 or t.shape[0] != n:
        raise ValueError(f"{what}: time has shape {t.shape}, expected ({n},)")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{what}: time has non-finite values")
    return t


def _time_column(timeline: str, t: np.ndarray) -> rr.TimeColumn:
    """A duration column in seconds (stored as integer nanoseconds)."""
    return rr.TimeColumn(timeline, duration=np.round(t * 1e9).astype("timedelta64[ns]"))


def _as_colors(colors, n: int | None = None) -> np.ndarray | None:
    """Colours as uint8 (n, 3|4) or (3|4,); floats are taken in 0..1."""
    if colors is None:
        return None
    c = np.asarray(colors)
    if np.issubdtype(c.dtype, np.floating):
        c = np.clip(np.round(c * 255.0), 0, 255)
    c = c.astype(np.uint8)
    if c.ndim not in (1, 2) or c.shape[-1] not in (3, 4):
        raise ValueError(f"colors must be (3|4,) or (N, 3|4), got shape {c.shape}")
    if n is not None and c.ndim == 2 and c.shape[0] != n:
        raise ValueError(f"colors has {c.shape[0]} rows, expected {n}")
    return c


def transforms_to_columns(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 4, 4) homogeneous transforms -> translations (T, 3) and quaternions xyzw (T, 4).

    The rotation blocks must be proper rotations (orthonormal, det +1).
    """
    T = np.asarray(T, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"transforms must have shape (T, 4, 4), got {T.shape}")
    quat = Rotation.from_matrix(T[:, :3, :3]).as_quat()  # scalar-last, as rerun
    return T[:, :3, 3].copy(), quat


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V, 3) of a triangle mesh (vectorised, ``np.add.at``)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for k in range(3):
        np.add.at(vn, f[:, k], fn)
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return np.divide(vn, norm, out=np.zeros_like(vn), where=norm > 0)


def _viewer_executable() -> str | None:
    """The ``rerun`` viewer installed next to this Python (a venv's bin/), found even when the
    venv is not activated; ``None`` lets rerun search PATH."""
    exe = Path(sys.executable).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    return str(exe) if exe.is_file() else None


class RerunSink(Sink):
    """Log to a rerun recording: an ``.rrd`` file, a spawned viewer, or both.

    Parameters
    ----------
    rrd : path of the ``.rrd`` file to write (complete after :meth:`close`); overwritten.
    spawn : open a rerun viewer and stream to it.
    app_id : the rerun application id (the viewer keys blueprints by it).
    blueprint : a ``rerun.blueprint.Blueprint`` to send; ``None`` sends
        :func:`viz.blueprint.default_blueprint`; ``False`` sends none (viewer heuristics).
    recording_id : fixes the recording id (default: a fresh UUID per sink).
    port : the spawned viewer's gRPC port.

    With neither ``rrd`` nor ``spawn`` the data stays in rerun's memory buffer (useful for tests
    that only check that logging runs).
    """

    enabled = True

    def __init__(self, rrd: str | Path | None = None, spawn: bool = False, app_id: str = "jointlab",
                 blueprint=None, recording_id: str | None = None, port: int = 9876):
        self.rrd = None if rrd is None else Path(rrd)
        self.spawn = bool(spawn)
        self.app_id = app_id
        if blueprint is None:
            blueprint = default_blueprint()
        elif blueprint is False:
            blueprint = None
        self.blueprint = blueprint
        self._rec = rr.RecordingStream(app_id, recording_id=recording_id or uuid.uuid4())
        if self.rrd is not None:
            self.rrd.parent.mkdir(parents=True, exist_ok=True)
        if self.spawn:
            rr.spawn(port=port, connect=False, executable_path=_viewer_executable())
            sinks = [rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy")]
            if self.rrd is not None:
                sinks.append(rr.FileSink(self.rrd))
            self._rec.set_sinks(*sinks, default_blueprint=blueprint)
        elif self.rrd is not None:
            self._rec.save(self.rrd, default_blueprint=blueprint)
        elif blueprint is not None:
            self._rec.send_blueprint(blueprint)

    # internals -----------------------------------------------------------------------------
    @property
    def recording(self) -> rr.RecordingStream:
        """The dedicated recording stream (for logging what the Sink interface does not cover)."""
        if self._rec is None:
            raise RuntimeError("this RerunSink is closed")
        return self._rec

    def _log(self, path: str, *archetypes, static: bool = True) -> None:
        self.recording.log(path, *archetypes, static=static, strict=_STRICT)

    def _send(self, path: str, time: np.ndarray, columns, timeline: str) -> None:
        self.recording.send_columns(path, indexes=[_time_column(timeline, time)], columns=columns,
                                    strict=_STRICT)

    # time series -------------------------------------------------------------------------
    def points_over_time(self, path, time, positions, labels=None, colors=None, radii=None,
                         timeline="time"):
        """One row per frame; occluded (non-finite) points are dropped frame by frame.

        ``labels`` (M,) and per-point ``colors`` (M, 3|4) follow their points; a single colour
        (3|4,) and ``radii`` are logged once, static, for the whole entity.
        """
        P = np.asarray(positions, dtype=float)
        if P.ndim != 3 or P.shape[2] != 3:
            raise ValueError(f"{path}: positions must be (T, M, 3), got {P.shape}")
        T, M = P.shape[:2]
        t = _check_time(time, T, path)
        ok = np.all(np.isfinite(P), axis=2)
        lengths = ok.sum(axis=1)
        fields = {"positions": P[ok]}
        if labels is not None:
            lab = np.asarray([str(x) for x in labels], dtype=object)
            if lab.shape != (M,):
                raise ValueError(f"{path}: {lab.shape[0]} labels for {M} markers")
            fields["labels"] = np.broadcast_to(lab, (T, M))[ok].tolist()
        c = _as_colors(colors)
        if c is not None and c.ndim == 2:
            if c.shape[0] != M:
                raise ValueError(f"{path}: {c.shape[0]} colors for {M} markers")
            fields["colors"] = np.broadcast_to(c, (T, M, c.shape[1]))[ok]
        static = {}
        if c is not None and c.ndim == 1:
            static["colors"] = c
        if radii is not None:
            static["radii"] = float(radii)
        if labels is not None:
            static["show_labels"] = True
        if static:
            self._log(path, rr.Points3D.from_fields(**static))
        cols = rr.Points3D.columns(**fields).partition(lengths)
        self._send(path, t, cols, timeline)

    def scalars(self, path, time, values, names=None, timeline="time"):
        """A (T,) series at ``path``; (T, k) with ``names``: one entity ``path/<name>`` per column;
        (T, k) without names: k series in the one entity. Non-finite samples are skipped (per
        column when named)."""
        V = np.asarray(values, dtype=float)
        if V.ndim not in (1, 2):
            raise ValueError(f"{path}: values must be (T,) or (T, k), got {V.shape}")
        t = _check_time(time, V.shape[0], path)
        if V.ndim == 1 and names is not None:
            V = V[:, None]
        if names is None:
            if V.ndim == 1:
                ok = np.isfinite(V)
                self._send(path, t[ok], rr.Scalars.columns(scalars=V[ok]), timeline)
            else:
                ok = np.all(np.isfinite(V), axis=1)
                k = V.shape[1]
                cols = rr.Scalars.columns(scalars=V[ok].ravel()).partition(np.full(int(ok.sum()), k))
                self._send(path, t[ok], cols, timeline)
            return
        names = [str(n) for n in names]
        if len(names) != V.shape[1]:
            raise ValueError(f"{path}: {len(names)} names for {V.shape[1]} columns")
        for k, name in enumerate(names):  # loop over columns, vectorised over samples
            child = _join(path, name)
            ok = np.isfinite(V[:, k])
            self._log(child, rr.SeriesLines(names=name))
            self._send(child, t[ok], rr.Scalars.columns(scalars=V[ok, k]), timeline)

    def transforms_over_time(self, path, time, T, timeline="time"):
        """``T_parent_path`` over time: translation + quaternion columns (one row per frame)."""
        trans, quat = transforms_to_columns(T)
        t = _check_time(time, trans.shape[0], path)
        cols = rr.Transform3D.columns(translation=trans, quaternion=quat)
        self._send(path, t, cols, timeline)

    # static content ----------------------------------------------------------------------
    def transform(self, path, T):
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"{path}: transform must be (4, 4), got {T.shape}")
        trans, quat = transforms_to_columns(T[None])
        self._log(path, rr.Transform3D(translation=trans[0], quaternion=quat[0]))

    def mesh(self, path, vertices, faces, color=None):
        V = np.asarray(vertices, dtype=np.float32)
        F = np.asarray(faces, dtype=np.uint32)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
            raise ValueError(f"{path}: mesh needs vertices (V, 3) and faces (F, 3), got "
                             f"{V.shape} and {F.shape}")
        if F.size and int(F.max()) >= V.shape[0]:
            raise ValueError(f"{path}: face index {int(F.max())} >= {V.shape[0]} vertices")
        c = _as_colors(color)
        self._log(path, rr.Mesh3D(vertex_positions=V, triangle_indices=F,
                                  vertex_normals=vertex_normals(V, F).astype(np.float32),
                                  albedo_factor=None if c is None else c))

    def points(self, path, positions, labels=None, colors=None, radii=None):
        P = np.asarray(positions, dtype=float).reshape(-1, 3)
        ok = np.all(np.isfinite(P), axis=1)
        kw = {}
        if labels is not None:
            lab = [str(x) for x in labels]
            if len(lab) != P.shape[0]:
                raise ValueError(f"{path}: {len(lab)} labels for {P.shape[0]} points")
            kw["labels"] = [lb for lb, k in zip(lab, ok) if k]
            kw["show_labels"] = True
        c = _as_colors(colors)
        if c is not None:
            kw["colors"] = c[ok] if c.ndim == 2 and c.shape[0] == P.shape[0] else c
        if radii is not None:
            kw["radii"] = float(radii)
        self._log(path, rr.Points3D(P[ok], **kw))

    def lines(self, path, strips, colors=None, radii=None):
        strips = [np.asarray(s, dtype=float).reshape(-1, 3) for s in strips]
        kw = {}
        c = _as_colors(colors)
        if c is not None:
            kw["colors"] = c
        if radii is not None:
            kw["radii"] = float(radii)
        self._log(path, rr.LineStrips3D(strips, **kw))

    def arrows(self, path, origins, vectors, labels=None, colors=None):
        O = np.asarray(origins, dtype=float).reshape(-1, 3)
        D = np.asarray(vectors, dtype=float).reshape(-1, 3)
        if O.shape != D.shape:
            raise ValueError(f"{path}: {O.shape[0]} origins for {D.shape[0]} vectors")
        kw = {}
        if labels is not None:
            kw["labels"] = [str(x) for x in labels]
            kw["show_labels"] = True
        c = _as_colors(colors)
        if c is not None:
            kw["colors"] = c
        self._log(path, rr.Arrows3D(origins=O, vectors=D, **kw))

    def text(self, path, markdown):
        self._log(path, rr.TextDocument(str(markdown), media_type=rr.MediaType.MARKDOWN))

    def image(self, path, rgb):
        a = np.asarray(rgb)
        if a.ndim != 3 or a.shape[2] not in (3, 4) or a.dtype != np.uint8:
            raise ValueError(f"{path}: image must be (H, W, 3|4) uint8, got {a.shape} {a.dtype}")
        self._log(path, rr.Image(a, color_model="RGB" if a.shape[2] == 3 else "RGBA"))

    def robot(self, path, meshes, time, link_transforms, timeline="time", axis_length=0.05):
        """Meshes once per link (static, at ``path/<link>``), each link's ``T_base_link`` over
        ``time`` via ``send_columns``. Links without a mesh show as coordinate axes."""
        t = np.asarray(time, dtype=float)
        for link, T in link_transforms.items():  # loop over links
            child = _join(path, link)
            if link in meshes:
                V, F = meshes[link][:2]
                self.mesh(child, V, F, color=meshes[link][2] if len(meshes[link]) > 2 else None)
            else:
                self._log(child, rr.TransformAxes3D(axis_length))
            self.transforms_over_time(child, t, T, timeline=timeline)

    # additions to the Sink interface -------------------------------------------------------
    def layout(self, series=None, world="/", text="/"):
        self.recording.send_blueprint(default_blueprint(world=world, series=series, text=text))

    # lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Flush everything and finish the ``.rrd`` (footer written); idempotent."""
        rec, self._rec = self._rec, None
        if rec is None:
            return
        try:
            rec.flush()
        except RuntimeError as exc:  # a viewer that never came up: the .rrd is still finished
            if not self.spawn:
                rec.disconnect()
                raise
            logging.getLogger(__name__).warning("rerun viewer unreachable (%s); %s", exc,
                                                f"the recording is in {self.rrd}" if self.rrd
                                                else "the data sent to it is lost")
        rec.disconnect()
