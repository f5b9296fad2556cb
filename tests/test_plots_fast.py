"""The cheaper figure path of viz.plots: one layout pass, direct PNG, paused GC."""
import gc
import weakref

import numpy as np
import pytest

mpl = pytest.importorskip("matplotlib")

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


def test_saved_png_has_the_pixels_savefig_draws(tmp_path):
    """One layout pass and a direct PNG: the pixels of ``savefig`` after ``Figure.tight_layout``."""
    from PIL import Image

    ref = _draw_single(vp.new_subplots(6.4, 4.4, dpi=110))
    ref.tight_layout()
    ref.savefig(tmp_path / "ref.png", format="png")
    fig = vp.tight_layout(_draw_single(vp.new_subplots(6.4, 4.4, dpi=110)))
    with Image.open(vp.save_png(fig, tmp_path / "one.png")) as a, Image.open(tmp_path / "ref.png") as b:
        assert np.array_equal(np.asarray(a.convert("RGB")), np.asarray(b.convert("RGB")))


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


class _Law:
    """A friction law stand-in: ``torque(v) = c sign(v) + k v``."""

    def __init__(self, c, k):
        self.c, self.k = c, k

    def torque(self, v):
        return self.c * np.sign(v) + self.k * np.asarray(v)


def test_friction_figures_drawn_on_one_figure_are_those_drawn_alone(tmp_path):
    """plot_friction_vs_speed_many redraws one figure: each PNG has the pixels of that figure
    drawn alone (data limits, colour cycle, legend and title of its own, none left over)."""
    from PIL import Image

    from ident.thesis.tables import plot_friction_vs_speed, plot_friction_vs_speed_many

    rng = np.random.default_rng(3)
    figures = []
    for k, (scale, models) in enumerate([
            (2.5, {"cv": _Law(3.0, 0.5), "stribeck": _Law(2.0, 1.0), "hyperbolic": _Law(1.0, 2.0)}),
            (0.004, {"cv": _Law(0.01, 0.3)}),                           # a much smaller range
            (40.0, {"a long model label": _Law(-200.0, -4.0), "b": _Law(50.0, 0.0)}),
            (1.0, {"cv": _Law(1.0, 0.1), "stribeck": _Law(0.9, 0.2)})]):
        qd = scale * rng.uniform(-1, 1, 700)
        f = models[next(iter(models))].torque(qd) + rng.normal(0, 0.1 * (1 + scale), qd.size)
        figures.append((f"f{k}.png", qd, f, models, f"figure {k}: range {scale:g} rad/s"))
    alone = [plot_friction_vs_speed(tmp_path / ("alone-" + n), *rest) for n, *rest in figures]
    many = plot_friction_vs_speed_many([(tmp_path / ("many-" + n), *rest) for n, *rest in figures])
    assert [p.name for p in many] == ["many-" + n for n, *_ in figures]
    for a, b in zip(alone, many):
        pa, pb = np.asarray(Image.open(a)), np.asarray(Image.open(b))
        assert pa.shape == pb.shape and np.array_equal(pa, pb), a.name
    assert plot_friction_vs_speed_many([]) == []
