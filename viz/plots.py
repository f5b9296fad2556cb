"""Matplotlib figures as images, headless (Agg), without pyplot's global state.

``new_figure`` makes a :class:`matplotlib.figure.Figure` bound to an Agg canvas (no display,
nothing registered with pyplot, so nothing leaks between calls); ``new_subplots`` makes one with
a grid of subplots from a pickled template (cheaper than building the Axes and their ticks);
``tight_layout`` sets the subplot parameters :meth:`~matplotlib.figure.Figure.tight_layout` sets,
at a fraction of its cost; ``figure_to_rgb`` renders any figure to an (H, W, 3) uint8 array,
e.g. for :meth:`viz.sink.Sink.image`; ``save_png`` writes a PNG (one draw) and refuses to
overwrite unless asked; ``young_garbage`` pauses cyclic garbage collection while figures are
drawn.
"""
from __future__ import annotations

from contextlib import contextmanager
import gc
from pathlib import Path
import pickle

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.transforms import Bbox, TransformNode
from matplotlib.layout_engine import PlaceHolderLayoutEngine


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


class _KeepAlivePickler(pickle.Pickler):
    """A pickler that holds on to every transform it pickles (``kept``)."""

    def __init__(self, file):
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.kept = []

    def persistent_id(self, obj):
        if isinstance(obj, TransformNode):
            self.kept.append(obj)
        return None   # pickled as usual


def _pickle_keeping_alive(obj) -> tuple:
    """(pickled ``obj``, every transform pickled). An unpickled matplotlib transform keys the
    transforms it invalidates by the ids they had when pickled (``TransformNode.__setstate__``);
    while those objects live no other object can take their ids, so no id collision drops a
    dependant from invalidation (which leaves e.g. an axis label at an old Axes position)."""
    import io

    buf = io.BytesIO()
    p = _KeepAlivePickler(buf)
    p.dump(obj)
    return buf.getvalue(), p.kept


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


_TEMPLATES: dict = {}   # (size, dpi, grid, ticks, rcParams) -> (pickled figure, objects kept alive)


def new_subplots(width_in: float = 6.4, height_in: float = 4.0, dpi: float = 100.0, nrows: int = 1,
                 ncols: int = 1, n: int | None = None, ticks: int = 11) -> Figure:
    """A figure as :func:`new_figure` makes it, holding the subplots ``1 .. n`` of an
    ``nrows`` x ``ncols`` grid (``fig.add_subplot(nrows, ncols, i)``; ``n`` = all by default),
    each axis already holding ``ticks`` major tick artists (and one minor).

    Matplotlib builds tick artists one at a time (two lines and two texts each), the dearest
    part of a small figure; this function builds the figure once per size, grid and rcParams,
    keeps it pickled, and returns a new unpickled copy on every call, so no figure is shared
    and nothing drawn on one reaches another. The copy draws as the freshly built figure does.

    Parameters
    ----------
    width_in, height_in : float, optional
        Size (inches).
    dpi : float, optional
        Pixels per inch.
    nrows, ncols : int, optional
        The grid.
    n : int, optional
        How many subplots, in row-major order.
    ticks : int, optional
        Major tick artists made in advance per axis (a draw adds the ones it lacks and leaves
        the others out): about the number the plot draws.

    Returns
    -------
    matplotlib.figure.Figure
        The figure; its Axes in ``fig.axes``.

    Examples
    --------
    >>> fig = new_subplots(3.0, 2.0, dpi=50, nrows=2, ncols=2, n=3)
    >>> len(fig.axes), figure_to_rgb(fig).shape
    (3, (100, 150, 3))
    >>> new_subplots(3.0, 2.0, dpi=50, nrows=2, ncols=2, n=3) is fig
    False
    """
    n = nrows * ncols if n is None else int(n)
    rc = hash(repr(sorted((k, v) for k, v in dict.items(mpl.rcParams) if k != "backend")))
    key = (float(width_in), float(height_in), float(dpi), int(nrows), int(ncols), n, ticks, rc)
    if key not in _TEMPLATES:
        fig = Figure(figsize=(width_in, height_in), dpi=dpi)
        for i in range(n):
            ax = fig.add_subplot(nrows, ncols, i + 1)
            for axis in (ax.xaxis, ax.yaxis):
                axis.get_major_ticks(ticks)
                axis.get_minor_ticks(1)
        _TEMPLATES[key] = _pickle_keeping_alive(fig)
    fig = pickle.loads(_TEMPLATES[key][0])
    FigureCanvasAgg(fig)
    return fig


def _layout_bbox(ax, renderer):
    """The tight bounding box of one Axes for the layout (display units), as
    ``ax.get_tightbbox(renderer, for_layout_only=True)`` gives it: the Axes, its axes' tick labels,
    labels and offset texts (the x label's width and the y label's height left out), its titles
    (their widths left out), its legend and its texts. Other artists are taken to be clipped to the
    Axes (as data artists are), so they are not measured."""
    bbs = [ax.get_window_extent(renderer)]
    if ax.axison:
        for axis in (ax.xaxis, ax.yaxis):
            if axis.get_visible():
                b = axis.get_tightbbox(renderer, for_layout_only=True)
                if b is not None:
                    bbs.append(b)
    if ax.yaxis.offsetText.get_text() or ax.xaxis.get_ticks_position() in ("top", "unknown") \
            or ax.xaxis.get_label_position() == "top":
        # the draw would move the titles above the offset text or top ticks: measure as matplotlib does
        return ax.get_tightbbox(renderer, for_layout_only=True)
    # nothing above the Axes for the titles to clear: they stay where they are (y = 1 + pad), so
    # the draw need not re-measure the y axis to place them (Axes._update_title_position)
    ax._autotitlepos = False
    for title in (ax.title, getattr(ax, "_left_title", None), getattr(ax, "_right_title", None)):
        if title is not None and title.get_visible() and title.get_text():
            bt = title.get_window_extent(renderer)
            bt.x0 = (bt.x0 + bt.x1) / 2 - 0.5   # its width does not count (tight_layout's rule)
            bt.x1 = bt.x0 + 1.0
            bbs.append(bt)
    legend = ax.get_legend()
    for a in ([legend] if legend is not None else []) + list(ax.texts):
        if a.get_visible() and a.get_in_layout():
            b = a.get_tightbbox(renderer)
            if b is not None and np.all(np.isfinite(b.extents)):
                bbs.append(b)
    return Bbox.union([b for b in bbs if b.width != 0 or b.height != 0])


def tight_layout(fig: Figure, pad: float = 1.08) -> Figure:
    """Set the subplot parameters that ``fig.tight_layout(pad=pad)`` sets, measuring each Axes
    once (:func:`_layout_bbox`) instead of through matplotlib's repeated tick updates, and leave
    no layout engine behind (so ``savefig`` lays nothing out again).

    The rule is matplotlib's (``_tight_layout._auto_adjust_subplotpars``): the margin on each side
    is the largest overhang of an Axes' tight box beyond its grid cell on that side plus ``pad``
    font sizes (rcParams ``font.size``), a suptitle adds its height and ``pad`` to the top margin,
    and the gaps between cells are the largest overhangs facing each other plus ``pad``. Figures
    that are not subplots of one grid, one Axes per cell (or whose Axes have a locator, a fixed
    aspect, twins or super labels) go through ``fig.tight_layout`` itself.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure, its artists in place.
    pad : float, optional
        Padding around and between the subplots, as a fraction of the font size.

    Returns
    -------
    matplotlib.figure.Figure
        ``fig``.

    Examples
    --------
    >>> fig = new_figure(3.0, 2.0, dpi=50)
    >>> ax = fig.add_subplot()
    >>> _ = ax.set_xlabel("x"), ax.set_ylabel("y"), ax.set_title("t")
    >>> p = tight_layout(fig).subplotpars
    >>> bool(0.0 < p.left < 0.5 < p.right < 1.0), bool(0.0 < p.bottom < 0.5 < p.top < 1.0)
    (True, True)
    """
    axes = [ax for ax in fig.axes if ax.get_visible()]
    specs = [ax.get_subplotspec() for ax in axes]
    grids = {s.get_gridspec() for s in specs if s is not None}
    simple = (axes and len(grids) == 1 and len(axes) == len(fig.axes)
              and all(s is not None and len(s.rowspan) == 1 and len(s.colspan) == 1 for s in specs)
              and len({(s.rowspan.start, s.colspan.start) for s in specs}) == len(specs)
              and not next(iter(grids)).locally_modified_subplot_params()
              and all(ax.get_axes_locator() is None and ax.get_aspect() == "auto" and not ax.child_axes
                      for ax in axes)
              and not getattr(fig, "_supxlabel", None) and not getattr(fig, "_supylabel", None))
    if not simple:
        fig.tight_layout(pad=pad)
        fig.set_layout_engine(None)
        return fig
    renderer = _agg_canvas(fig).get_renderer()
    rows, cols = next(iter(grids)).get_geometry()
    hspaces = np.zeros((rows, cols + 1))   # overhangs left of / right of each cell (figure fraction)
    vspaces = np.zeros((rows + 1, cols))   # overhangs above / below each cell
    to_fig = fig.transFigure.inverted()
    for ax, ss in zip(axes, specs):
        tb = to_fig.transform_bbox(_layout_bbox(ax, renderer))
        cell = ss.get_position(fig)
        r, c = ss.rowspan.start, ss.colspan.start
        hspaces[r, c] += cell.xmin - tb.xmin
        hspaces[r, c + 1] += tb.xmax - cell.xmax
        vspaces[r, c] += tb.ymax - cell.ymax
        vspaces[r + 1, c] += cell.ymin - tb.ymin
    w_in, h_in = fig.get_size_inches()
    pad_in = pad * FontProperties(size=mpl.rcParams["font.size"]).get_size_in_points() / 72
    left = max(float(hspaces[:, 0].max()), 0.0) + pad_in / w_in
    right = max(float(hspaces[:, -1].max()), 0.0) + pad_in / w_in
    top = max(float(vspaces[0, :].max()), 0.0) + pad_in / h_in
    bottom = max(float(vspaces[-1, :].max()), 0.0) + pad_in / h_in
    sup = getattr(fig, "_suptitle", None)
    if sup is not None and sup.get_in_layout():
        top += to_fig.transform_bbox(sup.get_window_extent(renderer)).height + pad_in / h_in
    kw = dict(left=left, right=1 - right, bottom=bottom, top=1 - top)
    if cols > 1:
        hspace = float(hspaces[:, 1:-1].max()) + pad_in / w_in
        kw["wspace"] = hspace / ((1 - right - left - hspace * (cols - 1)) / cols)
    if rows > 1:
        vspace = float(vspaces[1:-1, :].max()) + pad_in / h_in
        kw["hspace"] = vspace / ((1 - top - bottom - vspace * (rows - 1)) / rows)
    if left + right >= 1 or top + bottom >= 1 or kw.get("wspace", 1) <= 0 or kw.get("hspace", 1) <= 0:
        fig.tight_layout(pad=pad)   # no room: matplotlib warns and leaves the figure as it is
        fig.set_layout_engine(None)
        return fig
    fig.subplots_adjust(**kw)
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
