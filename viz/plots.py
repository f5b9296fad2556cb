"""Matplotlib figures as images, headless (Agg), without pyplot's global state.

``new_figure`` makes a :class:`matplotlib.figure.Figure` bound to an Agg canvas (no display,
nothing registered with pyplot, so nothing leaks between calls); ``new_subplots`` makes one with
a grid of subplots; ``tight_layout`` lays it out once (no second layout when saved);
``fixed_layout`` sets margins in inches without measuring text (cheaper still);
``clear_plotted`` readies a drawn figure's axes for the next plot of the same kind (one figure
redrawn instead of one built per plot); ``figure_to_rgb`` renders any figure to an (H, W, 3)
uint8 array, e.g. for :meth:`viz.sink.Sink.image`; ``save_png`` writes a PNG (one draw) and
refuses to overwrite unless asked; ``young_garbage`` pauses cyclic garbage collection while
figures are drawn.
"""
from __future__ import annotations

from contextlib import contextmanager
import gc
from pathlib import Path

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.layout_engine import PlaceHolderLayoutEngine
from matplotlib.ticker import AutoMinorLocator
from matplotlib.transforms import Bbox


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


@contextmanager
def young_garbage():
    """Cyclic garbage collection paused while figures are built and drawn, then one collection
    of the youngest generation (usable as a decorator of a plotting function: its figures are
    unreachable once it returns).

    A figure is a web of reference cycles of some ten thousand objects, so building one triggers
    automatic collections, now and then of the oldest generation, which walk every object of the
    process (about 0.1 s with a study's results in memory). With collection paused, the figures'
    objects stay in the youngest generation and one collection of it frees them (milliseconds).
    Collection is re-enabled only by the caller that found it enabled (nesting and threads are
    safe).

    Examples
    --------
    >>> with young_garbage():
    ...     _ = save_png  # draw here
    >>> gc.isenabled()
    True
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
            gc.collect(0)


def new_subplots(width_in: float = 6.4, height_in: float = 4.0, dpi: float = 100.0, nrows: int = 1,
                 ncols: int = 1, n: int | None = None) -> Figure:
    """A figure as :func:`new_figure` makes it, holding the subplots 1 to ``n`` of an
    ``nrows`` x ``ncols`` grid (``fig.add_subplot(nrows, ncols, i)``; ``n`` = all by default).

    Examples
    --------
    >>> fig = new_subplots(3.0, 2.0, dpi=50, nrows=2, ncols=2, n=3)
    >>> len(fig.axes), figure_to_rgb(fig).shape
    (3, (100, 150, 3))
    """
    n = nrows * ncols if n is None else int(n)
    fig = new_figure(width_in, height_in, dpi=dpi)
    for i in range(n):
        fig.add_subplot(nrows, ncols, i + 1)
    return fig


def tight_layout(fig: Figure, pad: float = 1.08) -> Figure:
    """Matplotlib's tight layout once, then no layout engine left on the figure: the subplot
    parameters are set once, and :func:`save_png` draws without laying the figure out again.

    Examples
    --------
    >>> fig = new_figure(3.0, 2.0, dpi=50)
    >>> ax = fig.add_subplot()
    >>> _ = ax.set_xlabel("x"), ax.set_ylabel("y"), ax.set_title("t")
    >>> p = tight_layout(fig).subplotpars
    >>> bool(0.0 < p.left < 0.5 < p.right < 1.0), fig.get_layout_engine() is None
    (True, True)
    """
    fig.tight_layout(pad=pad)
    fig.set_layout_engine(None)
    return fig


#: width of one character of a 10 pt DejaVu Sans tick label, inches (its mean advance, about
#: 0.55 em, rounded up): what :func:`fixed_layout` allows per character of the longest y label
CHAR_IN = 0.085


def fixed_layout(fig: Figure, left_in: float = 1.0, bottom_in: float = 0.5, right_in: float = 0.15,
                 top_in: float = 0.3, ylabels=()) -> Figure:
    """Margins in inches, set once without measuring any text (no layout engine left on the
    figure): the cheap alternative to :func:`tight_layout` for figures whose decorations are
    known in advance (one axes: an x label, a title, numeric y ticks with a y label, or
    category names on the y axis).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure (its subplot parameters are set).
    left_in, bottom_in, right_in, top_in : float, optional
        Margins (inches): y ticks and label, x ticks and label, the right edge, the title.
    ylabels : sequence of str, optional
        Category tick labels of the y axis; the left margin then grows to hold the longest
        (:data:`CHAR_IN` per character, plus 0.25 in), up to 0.6 of the width.

    Returns
    -------
    matplotlib.figure.Figure
        ``fig``, with no layout engine left on it.

    Examples
    --------
    >>> fig = new_subplots(6.0, 3.0, dpi=50)
    >>> p = fixed_layout(fig, ylabels=["stribeck", "position_ripple"]).subplotpars
    >>> float(round(p.left * 6.0, 3)), float(round((1 - p.top) * 3.0, 3)), fig.get_layout_engine() is None
    (1.525, 0.3, True)
    """
    w, h = fig.get_size_inches()
    longest = max((len(str(s)) for s in ylabels), default=0)
    left = max(left_in, 0.25 + CHAR_IN * longest) if longest else left_in
    left = min(left, 0.6 * w)
    fig.subplots_adjust(left=left / w, right=1 - right_in / w, bottom=bottom_in / h, top=1 - top_in / h)
    fig.set_layout_engine(None)
    return fig


def clear_plotted(ax) -> None:
    """Ready ``ax`` for the next plot of the same kind, as a new axes is before anything is
    plotted on it: the plotted artists (lines, bars and their containers, collections, patches,
    texts, images, tables) and the legend removed, the colour cycle at its first colour, the data
    limits empty, the view limits a new axes' (0, 1), autoscaling on, and an axis with units (a
    previous plot's category names) a plain numeric axis again (the next bars number theirs from
    0). Kept, to be set again the same way by each plot of the kind: the title, axis labels and
    scales, and the tick objects, canvas and renderer (the saving: no figure, axes and ticks built
    per plot). Redrawn this way, one figure gives the PNGs of a fresh figure per plot, byte for
    byte (``tests/test_plots_fast.py``).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        The axes (changed in place).

    Examples
    --------
    >>> fig = new_subplots(2.0, 1.0, dpi=50)
    >>> ax = fig.axes[0]
    >>> _ = ax.barh(["a", "b"], [1.0, 2.0]), ax.plot([0, 5], [0, 1])
    >>> clear_plotted(ax)
    >>> _ = ax.barh(["c"], [3.0])
    >>> float(ax.patches[0].get_y() + ax.patches[0].get_height() / 2), len(ax.lines)  # "c" at 0
    (0.0, 0)
    """
    for container in list(ax.containers):
        container.remove()  # its patches and lines with it
    for artists in (ax.lines, ax.patches, ax.collections, ax.texts, ax.images, ax.tables):
        for artist in list(artists):
            artist.remove()
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    ax.set_prop_cycle(None)
    for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
        if axis.have_units():  # e.g. the previous bars' category names: a numeric axis again
            axis.clear()  # (its label, scale, ticks and units as a new axes has them) ...
            handler = getattr(ax, "_unit_change_handler", None)
            if handler is not None:  # ... and the axes' own listener, which clear() drops
                axis.callbacks.connect("units", handler(name))
            if mpl.rcParams[f"{name}tick.minor.visible"]:  # as Axes.clear
                axis.set_minor_locator(AutoMinorLocator())
    ax.relim()
    # the view limits of a new axes, (0, 1) not yet set by anyone: autoscaling with no data (no
    # bars to draw) then gives a new axes' default view, not the previous plot's limits
    ax.viewLim.set_points(Bbox.unit().get_points())
    ax.set_autoscale_on(True)
    ax.stale = True


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

    At the figure's own resolution the figure is drawn once on its Agg canvas and the pixels
    written as they are: RGB when every pixel is opaque (RGBA otherwise), zlib level 1, the
    resolution and matplotlib's ``Software`` entry in the PNG header as ``savefig`` writes them.
    Another ``dpi`` goes through ``savefig``.

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
    canvas = _agg_canvas(fig)
    if isinstance(fig.get_layout_engine(), PlaceHolderLayoutEngine):
        fig.set_layout_engine(None)  # laid out already (tight_layout): no layout pass in savefig
    if dpi is not None and dpi != fig.dpi:
        fig.savefig(path, format="png", dpi=dpi)
        return path
    from PIL import Image, PngImagePlugin  # matplotlib's own dependency

    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    img = Image.frombuffer("RGBA", (rgba.shape[1], rgba.shape[0]), rgba, "raw", "RGBA", 0, 1)
    if int(rgba[..., 3].min()) == 255:
        img = img.convert("RGB")
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", f"Matplotlib version{mpl.__version__}, https://matplotlib.org/")
    img.save(path, format="png", dpi=(fig.dpi, fig.dpi), pnginfo=info, compress_level=1)
    return path
