"""The cheaper figure path of viz.plots: templates, one-pass tight layout, direct PNG, paused GC."""
import gc
import weakref

import numpy as np
import pytest

mpl = pytest.importorskip("matplotlib")
from matplotlib.transforms import TransformNode  # noqa: E402

from viz import plots as vp  # noqa: E402


def _draw_single(fig):
    ax = fig.axes[0]
    x = np.linspace(-1.3, 2.7, 500)
    ax.plot(x, 40 * np.sin(3 * x), ".", ms=1.5, label="data")
    ax.plot(x, 35 * np.tanh(x), lw=1.6, label="model")
    ax.set_xlabel("link speed qd (rad/s)")
    ax.set_ylabel("friction torque (N m)")
    ax.set_title("a title wider than the tick labels", fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    return fig


def _draw_grid(fig):
    for i, ax in enumerate(fig.axes):
        ax.plot(np.arange(4), (i + 1) * 10.0 ** (i - 2) * np.array([1, 3, 2, 5]), "o")
        ax.set_xticks(range(4))
        ax.set_xticklabels([f"{k}kg\n{10 * k}%" for k in range(4)], fontsize=7)
        ax.set_title(f"panel {i}", fontsize=9)
    fig.suptitle("a suptitle over the grid", fontsize=9)
    return fig


def _params(fig):
    p = fig.subplotpars
    return np.array([p.left, p.right, p.bottom, p.top, p.wspace, p.hspace])


def test_tight_layout_sets_matplotlibs_subplot_parameters():
    one = _draw_single(vp.new_subplots(6.4, 4.4, dpi=110))
    ref = _draw_single(vp.new_subplots(6.4, 4.4, dpi=110))
    ref.tight_layout()
    vp.tight_layout(one)
    assert np.allclose(_params(one), _params(ref), rtol=0, atol=1e-9)
    assert one.get_layout_engine() is None

    grid = _draw_grid(vp.new_subplots(9.6, 5.6, dpi=100, nrows=2, ncols=3, n=5))
    ref = _draw_grid(vp.new_subplots(9.6, 5.6, dpi=100, nrows=2, ncols=3, n=5))
    ref.tight_layout()
    vp.tight_layout(grid)
    assert np.allclose(_params(grid), _params(ref), rtol=0, atol=1e-9)
    assert len(grid.axes) == 5


def test_template_figure_draws_the_pixels_of_a_fresh_figure():
    fresh = vp.new_figure(6.4, 4.4, dpi=110)
    fresh.add_subplot()
    a = vp.figure_to_rgb(vp.tight_layout(_draw_single(fresh)))
    first = vp.new_subplots(6.4, 4.4, dpi=110)
    second = vp.new_subplots(6.4, 4.4, dpi=110)
    assert first is not second and first.axes[0] is not second.axes[0]
    _draw_single(first)  # drawing on one copy leaves the next one empty
    assert not second.axes[0].lines
    b = vp.figure_to_rgb(vp.tight_layout(_draw_single(second)))
    assert np.array_equal(a, b)


def test_unpickled_transforms_key_their_dependants_by_live_ids():
    """A transform's dependants are keyed by id: each key is its dependant's own id or the id of a
    template object kept alive, which no other object can take (else an id collision would drop a
    dependant from invalidation)."""
    fig = vp.new_subplots(6.0, 3.5, dpi=100, nrows=1, ncols=2)
    kept = {id(o) for _, objs in vp._TEMPLATES.values() for o in objs}
    seen, stack, keys = set(), [fig], 0
    while stack:
        o = stack.pop()
        if id(o) in seen:
            continue
        seen.add(id(o))
        if isinstance(o, TransformNode):
            for k, ref in o._parents.items():
                if ref() is not None:
                    keys += 1
                    assert k == id(ref()) or k in kept
        stack.extend(r for r in gc.get_referents(o) if not isinstance(r, (str, bytes, int, float, type)))
    assert keys > 100


def test_save_png_writes_the_drawn_pixels(tmp_path):
    from PIL import Image

    fig = vp.tight_layout(_draw_single(vp.new_subplots(4.0, 3.0, dpi=80)))
    with Image.open(vp.save_png(fig, tmp_path / "a.png")) as img:
        assert img.mode == "RGB" and img.size == (320, 240)
        assert img.info["dpi"] == pytest.approx((80, 80), abs=0.01)
        assert np.array_equal(np.asarray(img), vp.figure_to_rgb(fig))
    fig.patch.set_alpha(0.0)  # a transparent figure keeps its alpha channel
    with Image.open(vp.save_png(fig, tmp_path / "b.png")) as img:
        assert img.mode == "RGBA"


def test_young_garbage_frees_figures_and_restores_collection():
    @vp.young_garbage()
    def draw():
        fig = _draw_single(vp.new_subplots(4.0, 3.0, dpi=50))
        vp.figure_to_rgb(fig)
        assert not gc.isenabled()
        with vp.young_garbage():  # nested: the outer one re-enables
            pass
        assert not gc.isenabled()
        return weakref.ref(fig)

    assert gc.isenabled()
    ref = draw()
    assert gc.isenabled() and ref() is None
