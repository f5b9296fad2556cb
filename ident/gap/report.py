"""diagnosis.json, diagnosis.md and plots for a gap diagnosis."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ident.common import to_jsonable as _jsonable
from viz.plots import clear_plotted, fixed_layout, new_subplots, save_png, young_garbage


def _fmt(x, nd=3):
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:.{nd}g}"
    return str(x)


def _cell(x) -> str:
    """Markdown table cell text ('|' escaped)."""
    return str(x).replace("|", "\\|")


def _nominal_params(jp: dict) -> str:
    """One line on the nominal friction of a joint: fixed values and their source, or the
    shape parameters fitted or held."""
    def kv(d):
        return ", ".join(f"{k} = {_fmt(float(v), 4)}" for k, v in d.items())

    parts = []
    if "fixed_parameters" in jp:
        src = jp.get("from", [])
        src = ", ".join(src) if len(src) <= 2 else f"{src[0]} and {len(src) - 1} more entries"
        parts.append(f"fixed {kv(jp['fixed_parameters'])} (from {src}"
                     + (f"; {jp['aggregate']}" if jp.get("aggregate") else "") + ")")
    if jp.get("left_out"):
        parts.append(f"{len(jp['left_out'])} entries left out ({jp.get('left_out_why', '')})")
    if jp.get("held"):
        parts.append(f"shape held at {kv(jp['held'])}")
    if jp.get("shape_fitted"):
        parts.append(f"shape fitted {kv(jp['shape_fitted'])}")
    if jp.get("static_arctan"):
        parts.append(f"static arctan curve fitted {kv(jp['static_arctan'])}")
    if jp.get("shape_note"):
        parts.append(f"note: {jp['shape_note']}")
    return "; ".join(parts) + "."


def _channel_line(name: str, ch: dict) -> str:
    """One channel's line: held-out RMS before and after the selected effects with their 95 %
    intervals, the noise floors and the test's resolution."""
    lo, hi = ch["heldout_rms_nominal_ci95"]
    lo2, hi2 = ch["heldout_rms_final_ci95"]
    sel = ", ".join([s["effect"] for s in ch["selected"]]
                    + [f"{n} (a nuisance term: see the note)" for n in ch.get("nuisance", [])]) or "nothing"
    return (f"- **{name}** channel ({ch['unit']}): held-out RMS {ch['heldout_rms_nominal']:.4g} "
            f"[{lo:.4g}, {hi:.4g}] -> {ch['heldout_rms_final']:.4g} [{lo2:.4g}, {hi2:.4g}] "
            f"after adding {sel}; white-noise floor {ch['noise_floor_rms']:.3g} "
            f"(remaining gap {ch['remaining_gap_over_noise']:.2f}x the floor)"
            + (f"; noise from repetitions {ch['noise_floor_rms_repetitions']:.3g} (remaining gap "
               f"{ch['remaining_gap_over_repetition_noise']:.2f}x)" if ch.get("remaining_gap_over_repetition_noise")
               else "") + f"; {ch.get('n_blocks', '?')} blocks, smallest attainable p "
            f"{_fmt(ch.get('p_min_attainable'))}.")


def _localisation_tables(rep: dict) -> list:
    """Where the torque gap lies: the motion regimes' shares, then (records) the variables the
    held-out residual depends on."""
    L = [f"Where the torque gap lies ({rep.get('localisation_method', 'local refits')}):", "",
         "| regime | share |", "|---|---|"]
    L += [f"| {r['regime']} | {r['share']:.2f} |" for r in rep["localisation"]]
    if "localisation_rest" in rep:
        L.append(f"| rest | {rep['localisation_rest']:.2f} |")
    if rep.get("localisation_configuration"):
        L += ["", "What the held-out residual depends on (each variable's smooth functions fitted on the "
                  "other folds; share of the gap's excess over the noise floor they remove held out):", "",
              "| variable | share |", "|---|---|"]
        L += [f"| {r['variable']} | {r['share']:.2f} |" for r in rep["localisation_configuration"]]
    return L


def _effects_table(effects: list) -> list:
    """The candidate effects of the first selection step, one row each."""
    L = ["", "Candidate effects (first selection step; size = held-out variance removed over the "
             "channel's noise-floor variance, against the floor that effect-free campaigns set for "
             "that kind of candidate):", "",
         "| effect | channel | held-out RMS | reduction | p (Holm) | size / floor | significant | shape | "
         "confounded with |",
         "|---|---|---|---|---|---|---|---|---|"]
    for e in effects:
        if not e.get("identifiable", True):
            L.append(f"| {e['effect']} | {e['channel']} | - | - | - | - | no | {_cell(e['note'])} | "
                     f"{', '.join(e.get('confounded_with', []))} |")
            continue
        evd = e.get("evidence", {})
        size = (f"{evd['removed_variance_over_floor']:.3g} / {evd['effect_size_floor']:.2g}"
                if "removed_variance_over_floor" in evd and "effect_size_floor" in evd else "-")
        L.append(f"| {e['effect']} | {e['channel']} | {e['heldout_rms']:.4g} | {e['reduction']:.3f} | "
                 f"{e['p_adjusted']:.2g} | {size} | {'yes' if e['significant'] else 'no'} | {_cell(e['shape'])} | "
                 f"{', '.join(e.get('confounded_with', []))} |")
    return L


def markdown(report: dict, plots: dict) -> str:
    L = [f"# Sim-to-real gap diagnosis: {report['campaign']}", ""]
    nom = report.get("nominal") or {}
    L.append("Nominal model: the declared joint (rigid, or flexible at its declared stiffness), "
             "URDF rigid-body dynamics with small corrections, "
             + (nom.get("text") or "Coulomb + viscous friction") + "; its free parameters "
             "identified on the training folds; every figure below is on held-out folds "
             "(each joint's folds are named in diagnosis.json).")
    L.append("")
    if not report.get("link_angles"):
        L += ["> No link angles were available: only the torque channel was diagnosed.", ""]
    for j, rep in report["joints"].items():
        shown = rep["verdict"]
        if shown == "none" and rep.get("verdict_status") not in (None, "none", "effect"):
            shown = f"none ({str(rep['verdict_status']).replace('_', ' ')})"   # unexplained, insufficient data
        L += [f"## Joint {j}: verdict **{shown}**", ""]
        if "note" in rep:
            L += [rep["note"], ""]
            continue
        if rep.get("verdict_text"):
            L += [f"**Verdict**: {rep['verdict_text']}.", ""]
        for a in rep.get("alternatives", []):
            L += [f"- alternative **{a['effect']}**: {a['why']}; to separate: {a['separate_by']}."]
        if rep.get("alternatives"):
            L.append("")
        for note in rep.get("notes", []):
            L += [f"Note: {note}.", ""]
        if rep.get("unexplained"):
            L += [f"What stays unexplained: {rep['unexplained']}.", ""]
        nx = rep.get("next_experiment")
        if nx:
            L += ["Next experiment: " + "; ".join(f"{k}: {v}" for k, v in nx.items() if v is not None) + ".", ""]
        if rep.get("tests"):
            L += ["Tests: " + "; ".join(f"{c}: {t}" for c, t in rep["tests"].items()) + ".", ""]
        jm = (rep.get("nominal") or {}).get("joint_model")
        if jm:
            L += ["Joint model: " + jm["text"] + ".", ""]
        jp = (rep.get("nominal") or {}).get("joint_parameters")
        if jp:
            L += ["Nominal friction of this joint: " + _nominal_params(jp), ""]
        if rep.get("insufficient_data"):
            L += [f"Why: {rep['insufficient_data']}.", ""]
        L += [_channel_line(name, ch) for name, ch in rep["channels"].items()]
        L.append("")
        L += _localisation_tables(rep)
        if rep.get("payload_identified"):
            for key, e in rep["payload_identified"].items():
                if "com_flange_m" in e:
                    com = ", ".join(f"{c * 1e3:.1f} +- {s_ * 1e3:.1f}" for c, s_ in zip(e["com_flange_m"], e["com_stderr_m"]))
                    L += ["", f"Payload {key} ({', '.join(e.get('record_ids', []))}): identified in the nominal on "
                              f"every joint of every record, centre of mass in the flange frame [{com}] mm."]
        L += _effects_table(rep["effects"])
        ev = [(e["effect"], k, x) for e in rep["effects"] for k, x in e.get("evidence", {}).items()
              if k.startswith("unique_share_given_")]
        if ev:
            L += ["", "Signatures (share of an effect's own reduction that survives with its confounder in "
                      "the model; near 0 = explained by the confounder):", ""]
            L += [f"- {name}: {k.replace('_', ' ')} = {x:.2f}" for name, k, x in ev]
        v = next((e for e in rep["effects"] if e["effect"] == rep["verdict"]), None)
        if v:
            L += ["", f"To separate **{v['effect']}** from {', '.join(v['confounded_with']) or 'its neighbours'}: "
                      f"{v['separating_experiment']}. Bootstrap over trials: it gives the largest reduction in "
                      f"{100 * v.get('bootstrap_top_share', 0):.0f}% of resamples."]
        for key in (f"joint{j}_localisation", f"joint{j}_effects", f"joint{j}_residual", f"joint{j}_configuration",
                    f"joint{j}_spectrum"):
            if key in plots:
                L += ["", f"![{key}]({plots[key]})"]
        L.append("")
    return "\n".join(L)


#: the title's height on the plots whose y axis has no offset text (categories, log scale): set,
#: matplotlib does not measure every tick label to place it (a third of the drawing time)
FIXED_TITLE_Y = 1.0


def make_plots(report: dict, series: dict, out_dir: Path) -> dict:
    """The PNGs of each joint in ``out_dir`` (where the gap lies, candidate effects, residual
    against speed, residual spectrum): {key: file name}."""
    with young_garbage():
        return _draw_plots(report, series, out_dir)


def _draw_plots(report: dict, series: dict, out_dir: Path) -> dict:
    """The figures of :func:`make_plots`, drawn and saved: one figure per kind of plot, redrawn
    for each joint (:class:`_Figures`)."""
    paths = {}
    figures = _Figures()

    def subplots(figsize, kind):
        return figures.get(kind, figsize)

    def save(fig, key, ylabels=(), left_in=1.0):
        # margins fixed in advance (one axes, known decorations): no second pass over every text
        # to measure it for a tight layout (docs/performance.md, issue 47)
        fixed_layout(fig, left_in=left_in, ylabels=ylabels)
        save_png(fig, Path(out_dir) / f"{key}.png", overwrite=True)
        paths[key] = f"{key}.png"

    for j, rep in report["joints"].items():
        if "localisation" not in rep:
            continue
        fig, ax = subplots((6, 3), "localisation")
        loc = rep["localisation"]
        ax.barh([r["regime"] for r in loc][::-1], [r["share"] for r in loc][::-1], color="tab:blue")
        ax.set_xlabel("share of held-out torque gap")
        ax.set_title(f"joint {j}: where the gap lies", y=FIXED_TITLE_Y)
        save(fig, f"joint{j}_localisation", [r["regime"] for r in loc])
        eff = [e for e in rep["effects"] if e.get("identifiable", True)]
        fig, ax = subplots((6, 3.5), "effects")
        ax.barh([e["effect"] for e in eff][::-1], [e["reduction"] for e in eff][::-1],
                color=["tab:green" if e["significant"] else "tab:gray" for e in eff][::-1])
        ax.set_xlabel("held-out RMS reduction (fraction of nominal)")
        ax.set_title(f"joint {j}: candidate effects (green = significant)", y=FIXED_TITLE_Y)
        save(fig, f"joint{j}_effects", [e["effect"] for e in eff])
        s = series.get(j)
        if s is not None:
            fig, ax = subplots((6, 3.5), "residual")
            step = max(1, s["qd"].shape[0] // 20000)
            ax.plot(s["qd"][::step], s["residual_nominal"][::step], ".", ms=1, alpha=0.4)
            ax.set_xlabel("joint velocity [rad/s]")
            ax.set_ylabel("held-out torque residual [N m]")
            ax.set_title(f"joint {j}: nominal model residual")
            save(fig, f"joint{j}_residual")
            loc = rep.get("localisation_configuration") or []
            x = _variable_series(s, loc[0]["variable"]) if loc else None
            if x is not None:   # the residual against the variable it depends on most (held out)
                fig, ax = subplots((6, 3.5), "configuration")
                m = s["residual_nominal"] != 0
                ax.plot(x[m][::step], s["residual_nominal"][m][::step], ".", ms=1, alpha=0.4)
                ax.set_xlabel(f"{loc[0]['variable']}" + (" [rad]" if loc[0]["variable"].startswith("q") else ""))
                ax.set_ylabel("held-out torque residual [N m]")
                ax.set_title(f"joint {j}: residual vs {loc[0]['variable']} ({loc[0]['share']:.0%} of the excess, "
                             "held out)")
                save(fig, f"joint{j}_configuration")
            sp = s.get("spectrum") or {}
            if len(sp.get("f", ())) > 1:
                fig, ax = subplots((6, 3.5), "spectrum")
                ax.loglog(sp["f"][1:], sp["psd"][1:], label="held-out nominal residual")
                ax.axhline(sp["floor"], color="tab:red", ls="--", label="white-noise floor")
                ax.set_xlabel("frequency [Hz]")
                ax.set_ylabel("PSD [(N m)^2/Hz]")
                ax.set_title(f"joint {j}: residual spectrum against the noise floor", y=FIXED_TITLE_Y)
                ax.legend(fontsize=8)
                save(fig, f"joint{j}_spectrum", left_in=1.15)   # log ticks: "2 x 10^-3"
    return paths


class _Figures:
    """One figure per kind of plot of :func:`make_plots`, built the first time and cleared
    (:func:`viz.plots.clear_plotted`) each time after: the PNGs of a fresh figure per plot, byte
    for byte (tests/test_plots_fast.py), without building a figure, its axes and their ticks for
    each (docs/performance.md, issue 47)."""

    def __init__(self):
        self._figs = {}

    def get(self, kind: str, figsize):
        """The figure of ``kind`` (``figsize`` inches at 100 dpi) and its axes, with nothing
        plotted on it."""
        key = (kind, tuple(figsize))
        fig = self._figs.get(key)
        if fig is None:
            fig = self._figs[key] = new_subplots(*figsize, dpi=100)
        else:
            clear_plotted(fig.axes[0])
        return fig, fig.axes[0]


def _variable_series(s: dict, name: str):
    """The samples of a localisation variable (``q<k>``, ``velocity``, ``acceleration``, ``time``)
    in a joint's diagnosis series, or None."""
    if name.startswith("q") and s.get("q_all") is not None:
        return s["q_all"][:, int(name[1:]) - 1]
    return {"velocity": s.get("qd"), "acceleration": s.get("qdd"), "time": s.get("t")}.get(name)


def write_report(report: dict, series: dict, out_dir: Path, sink=None, plots: dict | None = None) -> dict:
    """Write diagnosis.json, diagnosis.md and PNG plots into ``out_dir``; log to ``sink``.
    ``plots``: the :func:`make_plots` result when the PNGs are already in ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if plots is None:
        plots = make_plots(report, series, out_dir)
    md = markdown(report, plots)
    paths = {"json": out_dir / "diagnosis.json", "md": out_dir / "diagnosis.md"}
    tmp = paths["json"].with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_jsonable(report), indent=1), encoding="utf-8")
    tmp.replace(paths["json"])
    paths["md"].write_text(md, encoding="utf-8")
    if sink is not None and sink.enabled:
        sink.text("diagnosis/report", md)
        for j, s in series.items():
            if s is None:
                continue
            sink.scalars(f"diagnosis/joint{j}/residual_nominal", s["t"] if "t" in s else np.arange(s["qd"].size),
                         s["residual_nominal"])
        try:
            import matplotlib.image as mpimg
            for key, name in plots.items():
                img = (mpimg.imread(out_dir / name)[..., :3] * 255).astype(np.uint8)
                sink.image(f"diagnosis/plots/{key}", img)
        except (OSError, ValueError):
            pass
    return paths
