"""Marker recordings: time-first arrays in metres."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError


@dataclass(frozen=True, eq=False)
class MarkerRecording:
    """A marker recording: labelled 3-D marker trajectories, time first, in metres.

    What the readers return, converted once at the file boundary (the marker file of the data
    format [1]_); the input of the per-frame link-angle solve of thesis ch. 3, eq. 3-3 to 3-5
    [2]_.

    Attributes
    ----------
    time : numpy.ndarray
        (T,) seconds, strictly increasing.
    positions : numpy.ndarray
        (T, M, 3) metres; NaN where a marker is occluded.
    labels : tuple of str
        M marker labels, unique.
    rate_hz : float
        The data rate declared by the file (or estimated from ``time`` if absent).
    units : str
        The unit declared by the source file (``"mm"`` or ``"m"``); ``positions`` are always
        metres.
    source : pathlib.Path or None
        The file it was read from, if any.
    meta : dict
        Extra header fields kept from the source file.

    Raises
    ------
    InputError
        If ``time`` is not 1-D, ``positions`` is not (T, M, 3) for M labels, or a label
        repeats (naming ``source``).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. Marker file (.trc).
    .. [2] PA10 thesis (seeds 002), ch. 3, eq. 3-3 to 3-5.

    Examples
    --------
    >>> rec = MarkerRecording(time=[0.0, 0.01], positions=np.zeros((2, 1, 3)), labels=["m1"],
    ...                       rate_hz=100.0)
    >>> rec.n_frames, rec.n_markers
    (2, 1)
    """

    time: np.ndarray
    positions: np.ndarray
    labels: tuple[str, ...]
    rate_hz: float
    units: str = "m"
    source: Path | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        t = np.asarray(self.time, dtype=float)
        p = np.asarray(self.positions, dtype=float)
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "labels", tuple(str(x) for x in self.labels))
        where = self.source
        if t.ndim != 1:
            raise InputError(f"time must be 1-D, got shape {t.shape}", path=where)
        if p.ndim != 3 or p.shape[2] != 3 or p.shape[0] != t.shape[0] or p.shape[1] != len(self.labels):
            raise InputError(
                f"positions must have shape (T={t.shape[0]}, M={len(self.labels)}, 3), got {p.shape}",
                path=where)
        if len(set(self.labels)) != len(self.labels):
            dup = sorted({x for x in self.labels if self.labels.count(x) > 1})
            raise InputError(f"duplicate marker labels {dup}", path=where)

    @property
    def n_frames(self) -> int:
        return int(self.time.shape[0])

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    def index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise InputError(f"marker {label!r} is not in this recording (labels: {', '.join(self.labels)})",
                             path=self.source, label=label) from None

    def marker(self, label: str) -> np.ndarray:
        """(T, 3) trajectory of one marker, metres."""
        return self.positions[:, self.index(label)]

    def select(self, labels) -> "MarkerRecording":
        """A recording with only ``labels``, in that order (raises naming any missing label)."""
        idx = [self.index(lb) for lb in labels]
        return MarkerRecording(self.time, self.positions[:, idx], tuple(labels), self.rate_hz,
                               self.units, self.source, dict(self.meta))

    def slice_time(self, t0: float, t1: float) -> "MarkerRecording":
        m = (self.time >= t0) & (self.time <= t1)
        return MarkerRecording(self.time[m], self.positions[m], self.labels, self.rate_hz,
                               self.units, self.source, dict(self.meta))

    @property
    def missing(self) -> np.ndarray:
        """(T, M) boolean: marker occluded in that frame."""
        return ~np.all(np.isfinite(self.positions), axis=2)

    def missing_fraction(self) -> dict[str, float]:
        frac = self.missing.mean(axis=0) if self.n_frames else np.zeros(self.n_markers)
        return {lb: float(f) for lb, f in zip(self.labels, frac)}

    def summary(self) -> dict:
        """The fields ``jointlab info --json`` prints for a marker file."""
        return {
            "path": None if self.source is None else str(self.source),
            "n_frames": self.n_frames,
            "n_markers": self.n_markers,
            "labels": list(self.labels),
            "rate_hz": float(self.rate_hz),
            "units": self.units,
            "first_time": float(self.time[0]) if self.n_frames else None,
            "last_time": float(self.time[-1]) if self.n_frames else None,
            "missing_fraction": self.missing_fraction(),
            "header_mismatch": list(self.meta.get("header_mismatch", [])),
        }
