"""Matplotlib figures as images, headless (Agg), without pyplot's global state.

``new_figure`` makes a :class:`matplotlib.figure.Figure` bound to an Agg canvas (no display,
nothing registered with pyplot, so nothing leaks between calls); ``figure_to_rgb`` renders any
figure to an (H, W, 3) uint8 array, e.g. for :meth:`viz.sink.Sink.image`; ``save_png`` writes a
PNG and refuses to overwrite unless asked.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def new_figure(width_in: float = 6.4, height_in: float = 4.0, dpi: float = 100.0, **kw) -> Figure:
    """A Figure on an Agg canvas (``**kw`` go to :class:`~matplotlib.figure.Figure`)."""
    fig = Figure(figsize=(width_in, height_in), dpi=dpi, **kw)
    FigureCanvasAgg(fig)
    return fig


def _agg_canvas(fig: Figure) -> FigureCanvasAgg:
    canvas = fig.canvas
    if not isinstance(canvas, FigureCanvasAgg):
        canvas = FigureCanvasAgg(fig)  # re-binds the figure to a headless canvas
    return canvas


def figure_to_rgb(fig: Figure) -> np.ndarray:
    """Render ``fig`` and return its pixels: (H, W, 3) uint8, H = height_in * dpi."""
    canvas = _agg_canvas(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[..., :3])


def save_png(fig: Figure, path: str | Path, overwrite: bool = False, dpi: float | None = None) -> Path:
    """Write ``fig`` as a PNG at ``path`` (parent folders created). Raises FileExistsError if the
    file exists and ``overwrite`` is false."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite (pass overwrite=True)")
    path.parent.mkdir(parents=True, exist_ok=True)
    _agg_canvas(fig)
    fig.savefig(path, format="png", dpi="figure" if dpi is None else dpi)
    return path
