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


def _gap_joint(rng, scale, regimes, effects, variable):
    """One joint's diagnosis report entry and series for ident.gap.report.make_plots, the data
    spanning about ``scale`` (velocities, residuals, spectrum)."""
    n = 3000
    t = np.arange(n) / 500.0
    qd = scale * np.sin(2 * np.pi * 0.3 * t) + 0.1 * scale * rng.normal(size=n)
    res = scale ** 2 * 0.02 * np.tanh(qd / scale) + 0.01 * scale * rng.normal(size=n)
    res[::7] = 0.0  # samples not held out
    f = np.linspace(0.0, 250.0, 120)
    rep = {"localisation": [{"regime": r, "share": s} for r, s in regimes],
           "effects": [{"effect": e, "reduction": r, "significant": r > 0.05, "identifiable": ok}
                       for e, r, ok in effects]}
    if variable:
        rep["localisation_configuration"] = [{"variable": variable, "share": 0.4}]
    s = {"t": t, "qd": qd, "qdd": np.gradient(qd, t), "residual_nominal": res,
         "q_all": np.cumsum(qd)[:, None] * np.array([1.0, -0.3, 2.0]) / 500.0,
         "spectrum": {"f": f, "psd": scale ** 3 * 1e-3 / (1.0 + f), "floor": scale ** 3 * 2e-5}}
    return rep, s


def test_gap_plots_on_reused_figures_are_those_of_fresh_figures(tmp_path):
    """make_plots redraws one figure per kind of plot for each joint: each joint's PNGs are,
    byte for byte, those of a make_plots call for that joint alone (a fresh figure per plot),
    whatever the previous joint left (data limits, colour cycle, bar categories, legend)."""
    from ident.gap.report import make_plots

    rng = np.random.default_rng(11)
    joints = {
        "1": _gap_joint(rng, 40.0, [("reversal", 0.5), ("low_speed", 0.3), ("high_speed", 0.1)],
                        [("stribeck", 0.3, True), ("time_offset", 0.01, True),
                         ("thermal_drift", -0.02, True)], "q2"),
        # a thousand times smaller, no identifiable effect (empty bars: a numeric axis), no variable
        "2": _gap_joint(rng, 0.04, [("high_acceleration", 0.9)], [("asymmetry", 0.2, False)], None),
        "3": _gap_joint(rng, 2.0, [("a_long_regime_name", 0.2), ("reversal", 0.7)],
                        [("position_ripple", 0.4, True), ("presliding", 0.0, True),
                         ("load_dependent", 0.02, True), ("nonlinear_viscous", 0.1, True),
                         ("cable", 0.06, True)], "velocity"),
    }
    report = {"joints": {j: rep for j, (rep, _) in joints.items()}}
    series = {j: s for j, (_, s) in joints.items()}
    together = make_plots(report, series, tmp_path / "together")
    alone = {}
    for j, (rep, s) in joints.items():
        alone.update(make_plots({"joints": {j: rep}}, {j: s}, tmp_path / "alone"))
    assert together == alone and len(together) == 14
    assert {"joint1_configuration", "joint3_configuration"} <= set(together)
    for key, name in together.items():
        a = (tmp_path / "together" / name).read_bytes()
        b = (tmp_path / "alone" / name).read_bytes()
        assert a == b, key
