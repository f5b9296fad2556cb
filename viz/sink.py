"""The logging seam. Other packages call a :class:`Sink`; only ``viz`` knows about rerun.

Every method takes plain numpy arrays, time first. ``NullSink`` (logging off) does nothing and
costs nothing. Entity paths are '/'-separated strings, e.g. ``"trials/j5-r1/markers"``.
"""
from __future__ import annotations

import numpy as np


class Sink:
    """The logging interface the other packages call; the base class logs nothing.

    Every method takes plain numpy arrays, time first, metres, under a '/'-separated entity
    path; only ``viz`` knows about rerun (:class:`viz.rerun_sink.RerunSink`) [1]_. Use as a
    context manager to :meth:`close` the recording.

    Attributes
    ----------
    enabled : bool
        Whether the sink records anything (False here and in :class:`NullSink`), so that
        callers can skip preparing what they would log.

    References
    ----------
    .. [1] jointlab design (docs/design.md), sec. Packages (``viz``).
    """

    enabled = False

    # time series -------------------------------------------------------------------------
    def points_over_time(self, path: str, time: np.ndarray, positions: np.ndarray,
                         labels=None, colors=None, radii: float | None = None,
                         timeline: str = "time") -> None:
        """Points (T, M, 3) in metres over ``time`` (T,), NaN points skipped."""

    def scalars(self, path: str, time: np.ndarray, values: np.ndarray, names=None,
                timeline: str = "time") -> None:
        """Scalar series (T,) or (T, k) under ``path`` (one child per column when named)."""

    def transforms_over_time(self, path: str, time: np.ndarray, T: np.ndarray,
                             timeline: str = "time") -> None:
        """Homogeneous transforms (T, 4, 4) of the entity ``path`` relative to its parent."""

    # static content ----------------------------------------------------------------------
    def transform(self, path: str, T: np.ndarray) -> None:
        """A fixed transform (4, 4) of ``path`` relative to its parent."""

    def mesh(self, path: str, vertices: np.ndarray, faces: np.ndarray, color=None) -> None:
        """A triangle mesh, static, in the frame of ``path``."""

    def points(self, path: str, positions: np.ndarray, labels=None, colors=None,
               radii: float | None = None) -> None:
        """Static points (M, 3)."""

    def lines(self, path: str, strips, colors=None, radii: float | None = None) -> None:
        """Static line strips: a list of (K_i, 3) arrays."""

    def arrows(self, path: str, origins: np.ndarray, vectors: np.ndarray, labels=None,
               colors=None) -> None:
        """Static arrows (M, 3) + (M, 3)."""

    def text(self, path: str, markdown: str) -> None:
        """A Markdown document."""

    def image(self, path: str, rgb: np.ndarray) -> None:
        """An (H, W, 3|4) uint8 image (e.g. a rendered plot)."""

    def robot(self, path: str, meshes: dict, time: np.ndarray, link_transforms: dict,
              timeline: str = "time") -> None:
        """A robot: ``meshes`` maps link name -> (vertices, faces) in the link frame;
        ``link_transforms`` maps link name -> (T, 4, 4) ``T_base_link`` over ``time``."""

    # lifecycle ---------------------------------------------------------------------------
    def close(self) -> None:
        """Flush and finish the recording (the .rrd is complete after this)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # layout (appended) -------------------------------------------------------------------
    def layout(self, series=None, world: str = "/", text: str = "/") -> None:
        """Ask the viewer for the default layout with these time-series views:
        ``series`` maps a view name to entity path filters (see :mod:`viz.blueprint`)."""


class NullSink(Sink):
    """The sink used when logging is off: every call does nothing and costs nothing.

    Attributes
    ----------
    enabled : bool
        False.

    References
    ----------
    .. [1] jointlab design (docs/design.md), sec. Packages (``viz``).
    """


def make_sink(rrd: str | None = None, spawn: bool = False, app_id: str = "jointlab") -> Sink:
    """The sink of a command: a rerun sink when ``rrd`` or ``spawn`` is asked for, else null.

    What every command's ``--rrd FILE`` and ``--spawn`` options give [1]_; rerun is imported
    only when a recording is asked for.

    Parameters
    ----------
    rrd : str or None, optional
        Save the recording to this .rrd file.
    spawn : bool, optional
        Open the viewer (default False).
    app_id : str, optional
        The rerun application id (default ``"jointlab"``).

    Returns
    -------
    Sink
        A :class:`viz.rerun_sink.RerunSink`, or a :class:`NullSink` when neither ``rrd`` nor
        ``spawn`` is given.

    References
    ----------
    .. [1] jointlab design (docs/design.md), sec. Conventions.

    Examples
    --------
    >>> type(make_sink()).__name__
    'NullSink'
    """
    if not rrd and not spawn:
        return NullSink()
    from viz.rerun_sink import RerunSink

    return RerunSink(rrd=rrd, spawn=spawn, app_id=app_id)
