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
    """A Figure on an Agg canvas (``**kw`` go to :class:`~matplotlib.figure.Figure`).

    Parameters
    ----------
    width_in, height_in : float, optional
        Size (inches).
    dpi : float, optional
        Pixels per inch.
    **kw
        Further arguments of :class:`~matplotlib.figure.Figure`.

    Returns
    -------
    matplotlib.figure.Figure
        A figure that renders without a display and is not registered with pyplot.

    Examples
    --------
    >>> fig = new_figure(2.0, 1.0, dpi=50)
    >>> ax = fig.add_subplot()
    >>> _ = ax.plot([0, 1], [0, 1])
    >>> figure_to_rgb(fig).shape
    (50, 100, 3)
    """
    fig = Figure(figsize=(width_in, height_in), dpi=dpi, **kw)
    FigureCanvasAgg(fig)
    return fig


def _agg_canvas(fig: Figure) -> FigureCanvasAgg:
    canvas = fig.canvas
    if not isinstance(canvas, FigureCanvasAgg):
        canvas = FigureCanvasAgg(fig)  # re-binds the figure to a headless canvas
    return canvas


def figure_to_rgb(fig: Figure) -> np.ndarray:
    """Render ``fig`` and return its pixels: (H, W, 3) uint8, H = height_in * dpi.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Any figure (re-bound to an Agg canvas when it has another).

    Returns
    -------
    numpy.ndarray
        The RGB pixels, (H, W, 3) uint8.

    Examples
    --------
    >>> rgb = figure_to_rgb(new_figure(1.0, 1.0, dpi=20))
    >>> rgb.shape, rgb.dtype.name, int(rgb.min())
    ((20, 20, 3), 'uint8', 255)
    """
    canvas = _agg_canvas(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[..., :3])


def save_png(fig: Figure, path: str | Path, overwrite: bool = False, dpi: float | None = None) -> Path:
    """Write ``fig`` as a PNG at ``path`` (parent folders created).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    path : str or pathlib.Path
        The PNG file.
    overwrite : bool, optional
        Replace an existing file.
    dpi : float, optional
        Resolution; the figure's own by default.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    FileExistsError
        If the file exists and ``overwrite`` is false.

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = save_png(new_figure(1.0, 1.0, dpi=20), Path(d) / "plots" / "a.png")
    ...     p.read_bytes()[1:4] == b"PNG", p.name
    (True, 'a.png')
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite (pass overwrite=True)")
    path.parent.mkdir(parents=True, exist_ok=True)
    _agg_canvas(fig)
    fig.savefig(path, format="png", dpi="figure" if dpi is None else dpi)
    return path
