"""Statistics over a study: the thesis's Tables 5-1 to 5-3 and A-1 to B-2 (002, ch. 5).

Input is a list of *fit records*, one per (trial, joint, model), plain dicts::

    {"trial": id, "joint": 5, "load_kg": 3.373, "vmax_frac": 1.0, "repetition": 1,
     "model": "cv", "params": {...}, "stderr": {...}, "rms": 0.31,
     "max_abs_tau": 12.0, "peak_speed": 2.43}

Groups are (joint, load, speed range); within a group (the repetitions) each parameter gets
its mean and coefficient of variation ``CV% = 100 std / |mean|``. The thesis's CV values are
those of the population standard deviation (ddof = 0): one non-zero value out of five gives
exactly 200.00 %, which Tables 5-1, A-1, A-3 print. The RMS table (5-3, B-1, B-2) gives the mean
RMS error (N m), its CV% and its percentage of the maximum absolute motor torque of the trial
(averaged over the repetitions). "Extra load" is printed in newtons (``load_kg * g``) and
"Maximum velocity" is the mean measured peak link speed of the group (rad/s), as in the thesis.
In Markdown a mean that rounds to 0.00 prints as ``<0.01`` with CV ``n/a`` (thesis style).
"""
from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

import numpy as np
from ident.friction.plausibility import meaning_line
from viz.plots import fixed_layout, new_subplots, save_png, young_garbage

__all__ = ["mean_cv", "group_records", "summarize", "excluded_fits", "rms_summary", "param_table", "rms_table",
           "write_table", "write_tables", "plot_friction_vs_speed", "plot_friction_vs_speed_many",
           "PARAM_NAMES", "MODEL_TITLES"]

G = 9.81
PARAM_NAMES = {"cv": ("c", "v"), "stribeck": ("Fk", "Fv", "Fs", "Vc"),
               "hyperbolic": ("g1", "g2", "g3", "g4", "g5", "g6"),
               "arctan": ("tau_s", "tau_sc", "tau_v", "tau_nlv", "delta")}
MODEL_TITLES = {"cv": "Coulomb + viscous model", "stribeck": "Four-parameter Stribeck model",
                "hyperbolic": "Six-parameter hyperbolic model",
                "arctan": "Arctangent model (Indri & Trapani eq. 1-2)"}
_PRINT_NAMES = {"Fk": "F_k", "Fv": "F_v", "Fs": "F_s", "Vc": "V_c", "g1": "γ_1", "g2": "γ_2",
                "g3": "γ_3", "g4": "γ_4", "g5": "γ_5", "g6": "γ_6"}


def mean_cv(values) -> tuple[float, float]:
    """Mean and CV% (population std / |mean| * 100) of repeated estimates; CV is NaN when the
    mean is 0 or there are no finite values."""
    x = np.asarray(values, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    m = float(x.mean())
    cv = float(100.0 * x.std() / abs(m)) if m != 0 else float("nan")
    return m, cv


def _key(r):
    return (int(r["joint"]), float(r["load_kg"]), float(r["vmax_frac"]))


def group_records(records) -> dict:
    """{(joint, load_kg, vmax_frac): {model: [records]}}, groups in thesis order (joint up,
    load down, speed range down)."""
    groups = defaultdict(lambda: defaultdict(list))
    for r in records:
        groups[_key(r)][r["model"]].append(r)
    order = sorted(groups, key=lambda k: (k[0], -k[1], -k[2]))
    return {k: dict(groups[k]) for k in order}


def _none(x):
    return None if x is None or not np.isfinite(x) else float(x)


def _valid(recs, param: str | None = None) -> list:
    """The records without a physical-validity flag (``flags``) and, for ``param``, those in
    which the fit determined it (not in ``unidentified``, see :data:`UNIDENTIFIED`): only
    these enter means."""
    return [r for r in recs if not r.get("flags")
            and (param is None or (param not in UNIDENTIFIED.get(r.get("degenerate"), ())
                                   and param not in r.get("param_flags", {})))]


UNIDENTIFIED = {"hyperbolic_stribeck_nonunique": ("g1", "g2", "g3"), "stribeck_as_cv": ("Vc",),
                "stribeck_Vc_at_bound": ("Vc",)}
"""Parameters a degenerate form leaves undetermined (their value is arbitrary along a valley
of equal fits): left out of that parameter's mean and CV."""


def excluded_fits(records) -> list[dict]:
    """The fits kept out of the condition means: ``{trial, joint, model, flags}``."""
    return [{"trial": r.get("trial"), "joint": int(r["joint"]), "load_kg": float(r["load_kg"]),
             "vmax_frac": float(r["vmax_frac"]), "model": r["model"], "flags": list(r["flags"])}
            for r in records if r.get("flags")]


def summarize(records) -> list[dict]:
    """The ``summary`` list of fits.json: ``{joint, load_kg, vmax_frac, model, param, mean,
    cv_percent, n, n_excluded}`` for every parameter of every model in every group. Fits with a
    physical-validity flag (a negative Coulomb or Stribeck level, wrong hyperbolic signs) are
    kept out of the mean and CV (``n_excluded``), and so are, for one parameter, the fits whose
    degenerate form leaves it undetermined (:data:`UNIDENTIFIED`)."""
    out = []
    for (j, load, vf), by_model in group_records(records).items():
        for model, recs in by_model.items():
            names = list(recs[0]["params"])
            for p in names:
                good = _valid(recs, p)
                m, cv = mean_cv([r["params"].get(p, np.nan) for r in good])
                out.append({"joint": j, "load_kg": load, "vmax_frac": vf, "model": model, "param": p,
                            "mean": _none(m), "cv_percent": _none(cv), "n": len(good),
                            "n_excluded": len(recs) - len(good)})
    return out


def rms_summary(records) -> list[dict]:
    """Per group and model: mean RMS (N m), its CV%, its percentage of the maximum motor
    torque, and the group's mean peak speed (rad/s)."""
    out = []
    for (j, load, vf), by_model in group_records(records).items():
        for model, recs in by_model.items():
            m, cv = mean_cv([r["rms"] for r in recs])
            pct = [100.0 * r["rms"] / r["max_abs_tau"] for r in recs if r.get("max_abs_tau")]
            out.append({"joint": j, "load_kg": load, "vmax_frac": vf, "model": model,
                        "rms_mean": _none(m), "rms_cv_percent": _none(cv),
                        "rms_percent_max_torque": _none(float(np.mean(pct)) if pct else np.nan),
                        "peak_speed": _none(float(np.mean([r.get("peak_speed", np.nan) for r in recs]))),
                        "n": len(recs)})
    return out


# ---------------------------------------------------------------------------------------------
# tables
# ---------------------------------------------------------------------------------------------
def _peak(by_model):
    recs = next(iter(by_model.values()))
    return float(np.mean([r.get("peak_speed", np.nan) for r in recs]))


def param_table(records, joint: int, models=("cv", "stribeck")) -> tuple[list, list]:
    """Table 5-1 / 5-2 / A-x layout for one joint: header and rows ``[joint, load (N), maximum
    velocity (rad/s), statistic ("mean" | "CV(%)"), params...]`` with numbers as floats (NaN
    where absent)."""
    header = ["Joint", "Extra load (N)", "Maximum velocity (rad/s)", "Statistic"]
    cols = [(m, p) for m in models for p in PARAM_NAMES.get(m, ())]
    header += [f"{m}:{p}" for m, p in cols]
    rows = []
    for (j, load, vf), by_model in group_records(records).items():
        if j != joint:
            continue
        stats = {}
        for m, p in cols:
            recs = _valid(by_model.get(m, []), p)
            stats[(m, p)] = mean_cv([r["params"].get(p, np.nan) for r in recs]) if recs else (np.nan, np.nan)
            allr = by_model.get(m, [])
            if not recs and allr and all(
                    r.get("param_flags", {}).get(p, {}).get("flag") == "unidentifiable"
                    or p in UNIDENTIFIED.get(r.get("degenerate"), ()) for r in allr):
                stats[(m, p)] = ("not identifiable", "n/a")   # printed as such, not as a number
        base = [j, load * G, _peak(by_model)]
        rows.append(base + ["mean"] + [stats[c][0] for c in cols])
        rows.append(base + ["CV(%)"] + [stats[c][1] for c in cols])
    return header, rows


def rms_table(records, joint: int, models=("cv", "stribeck", "hyperbolic")) -> tuple[list, list]:
    """Table 5-3 / B-x layout for one joint: rows ``[joint, load (N), maximum velocity,
    "mean(Nm)" | "CV(%)" | "percentage(%)", one column per model]``."""
    header = ["Joint", "Extra load (N)", "Maximum velocity (rad/s)", "RMS error"] + list(models)
    rows = []
    summ = {(r["joint"], r["load_kg"], r["vmax_frac"], r["model"]): r for r in rms_summary(records)}
    for (j, load, vf), by_model in group_records(records).items():
        if j != joint:
            continue
        base = [j, load * G, _peak(by_model)]
        for label, key in (("mean(Nm)", "rms_mean"), ("CV(%)", "rms_cv_percent"),
                           ("percentage(%)", "rms_percent_max_torque")):
            vals = []
            for m in models:
                s = summ.get((j, load, vf, m))
                v = s[key] if s else None
                vals.append(np.nan if v is None else v)
            rows.append(base + [label] + vals)
    return header, rows


def _fmt(x) -> str:
    if isinstance(x, str):
        return x
    if x is None or not np.isfinite(x):
        return "n/a"
    return f"{x:.2f}"


def _markdown(title, header, rows, models_header=None) -> str:
    pretty = []
    for h in header:
        if ":" in h:
            m, p = h.split(":", 1)
            pretty.append(_PRINT_NAMES.get(p, p))
        else:
            pretty.append(MODEL_TITLES.get(h, h))
    lines = [f"**{title}**", ""]
    if models_header:
        lines.append("| " + " | ".join(models_header) + " |")
        lines.append("|" + "---|" * len(models_header))
        lines.append("| " + " | ".join(pretty) + " |")
    else:
        lines.append("| " + " | ".join(pretty) + " |")
        lines.append("|" + "---|" * len(pretty))
    prev = None
    is_params = any(":" in h for h in header)
    small = []
    for row in rows:
        cells = [str(row[0]), _fmt(row[1]), _fmt(row[2]), row[3]]
        key = tuple(cells[:3])
        if key == prev:  # thesis style: the group's labels once
            cells[:3] = ["", "", ""]
        prev = key
        vals = row[4:]
        if row[3] == "mean" and is_params:
            small = [bool(not isinstance(v, str) and np.isfinite(v) and abs(v) < 0.005) for v in vals]
            out = ["<0.01" if s_ else _fmt(v) for v, s_ in zip(vals, small)]
        elif row[3] == "CV(%)" and is_params:
            out = ["n/a" if s_ else _fmt(v) for v, s_ in zip(vals, small)]
        else:
            out = [_fmt(v) for v in vals]
        lines.append("| " + " | ".join(cells + out) + " |")
    return "\n".join(lines) + "\n"


def _footnotes(records, joint: int, models) -> str:
    """Markdown footnote listing the fits of ``joint``/``models`` kept out of the means, and
    those whose errors-in-variables bias exceeds their standard error."""
    bad = [r for r in records if int(r["joint"]) == joint and r["model"] in models and r.get("flags")]
    eiv = [r for r in records if int(r["joint"]) == joint and r["model"] in models and r.get("eiv_exceeds_se")]
    lines = ["Viscous coefficients (v, F_v, γ_6) are in the link-only basis: the motor viscous B of "
             "drives.toml is removed in the eq. 2-4 target; link + motor viscous is v + B."]
    if bad:
        lines.append(f"Excluded from the means and CVs ({len(bad)} physically impossible fit(s)):")
        lines += [f"- {r.get('trial')} ({r['model']}): {'; '.join(r['flags'])}" for r in bad]
    und = [r for r in records if int(r["joint"]) == joint and r["model"] in models and not r.get("flags")
           and UNIDENTIFIED.get(r.get("degenerate"))]
    if und:
        lines.append(f"Left out of single parameters' means ({len(und)} fit(s) in a degenerate form that "
                     "does not determine them):")
        lines += [f"- {r.get('trial')} ({r['model']}, {r['degenerate']}): "
                  f"{', '.join(UNIDENTIFIED[r['degenerate']])}" for r in und]
    pf: dict = {}
    for r in records:
        if int(r["joint"]) == joint and r["model"] in models and not r.get("flags"):
            for k, f in r.get("param_flags", {}).items():
                pf.setdefault((r.get("trial"), r["model"], f["flag"], f["reason"]), []).append(k)
    if pf:
        lines.append("Parameters flagged by the plausibility check (ident.friction.plausibility) "
                     "and left out of their means:")
        lines += [f"- {tr} ({m}) {', '.join(ks)}: {kind} ({why})"
                  for (tr, m, kind, why), ks in pf.items()]

    chk = [r for r in records if int(r["joint"]) == joint and r["model"] in models and r.get("input_checks")]
    if chk:     # ident.friction.plausibility.input_checks (issue 45): shown, not excluded
        lines.append(f"Input checks failed ({len(chk)} fit(s); the warning of `jointlab fit` names the "
                     "input mistakes that would explain them):")
        lines += [f"- {r.get('trial')} ({r['model']}): {'; '.join(r['input_checks'])}" for r in chk]
    lines += [meaning_line(m) + "." for m in models if meaning_line(m)]
    if eiv:
        lines.append(f"Errors in variables: in {len(eiv)} fit(s) the link-state noise biases a parameter "
                     "by more than its standard error (fits_diagnostics.json, `eiv`): "
                     + ", ".join(f"{r.get('trial')} ({r['model']})" for r in eiv))
    return "\n" + "\n".join(lines) + "\n"


def write_table(out_base: Path, title: str, header, rows, footnote: str = "") -> tuple[Path, Path]:
    """Write ``out_base.csv`` (raw numbers, header as given) and ``out_base.md`` (thesis
    formatting, then ``footnote``); returns both paths."""
    out_base = Path(out_base)
    out_base.parent.mkdir(parents=True, exist_ok=True)
    csv_path, md_path = out_base.with_suffix(".csv"), out_base.with_suffix(".md")
    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in rows:
            w.writerow([("" if (isinstance(x, float) and not np.isfinite(x)) else
                         (repr(float(x)) if isinstance(x, (float, np.floating)) else x)) for x in row])
    models_header = None
    param_cols = [h for h in header if ":" in h]
    if param_cols:
        models_header = [""] * 4
        prev = None
        for h in header[4:]:
            m = h.split(":")[0]
            models_header.append(MODEL_TITLES.get(m, m) if m != prev else "")
            prev = m
    md_path.write_text(_markdown(title, header, rows, models_header) + footnote, encoding="utf-8")
    return csv_path, md_path


def write_tables(records, out_dir: str | Path, models=("cv", "stribeck", "hyperbolic")) -> list[Path]:
    """All thesis tables for every joint in ``records`` into ``out_dir``:
    ``params_cv_stribeck_joint<j>`` (Table 5-1 / A-odd), ``params_hyperbolic_joint<j>``
    (Table 5-2 / A-even), ``rms_joint<j>`` (Table 5-3 / B), each .csv + .md, plus
    ``tables.md`` with all of them."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    joints = sorted({int(r["joint"]) for r in records})
    present = [m for m in models if any(r["model"] == m for r in records)]
    written, md = [], []
    for j in joints:
        first = [m for m in ("cv", "stribeck") if m in present]
        if first:
            h, rows = param_table(records, j, first)
            title = (f"Friction parameter identification results of "
                     f"{' and '.join(MODEL_TITLES[m] for m in first)} for joint {j}.")
            written += write_table(out_dir / f"params_{'_'.join(first)}_joint{j}", title, h, rows,
                                   _footnotes(records, j, first))
            md.append(written[-1].read_text(encoding="utf-8"))
        for m in ("hyperbolic", "arctan"):
            if m not in present:
                continue
            h, rows = param_table(records, j, (m,))
            title = f"Friction parameter identification results of {m} model for joint {j}."
            written += write_table(out_dir / f"params_{m}_joint{j}", title, h, rows,
                                   _footnotes(records, j, (m,)))
            md.append(written[-1].read_text(encoding="utf-8"))
        h, rows = rms_table(records, j, tuple(present))
        count = {1: "one", 2: "two", 3: "three"}.get(len(present), str(len(present)))
        title = f"Root mean square error of {count} different friction models for joint {j}."
        written += write_table(out_dir / f"rms_joint{j}", title, h, rows)
        md.append(written[-1].read_text(encoding="utf-8"))
    all_md = out_dir / "tables.md"
    all_md.write_text("\n".join(md), encoding="utf-8")
    written.append(all_md)
    return written


# ---------------------------------------------------------------------------------------------
# plots
# ---------------------------------------------------------------------------------------------
def plot_friction_vs_speed(path: str | Path, qd, f_measured, models: dict, title: str = "") -> Path:
    """Friction torque vs link speed (thesis Figs. 5-1, 5-2): the measured friction
    (eq. 2-4 target minus the fitted rigid part) as dots and each fitted model as a curve.
    ``models``: {label: object with ``torque(qd)``}. Saved as PNG with matplotlib (Agg)."""
    return plot_friction_vs_speed_many([(path, qd, f_measured, models, title)])[0]


def plot_friction_vs_speed_many(figures) -> list[Path]:
    """:func:`plot_friction_vs_speed` of each ``(path, qd, f_measured, models, title)`` of
    ``figures``, drawn on one figure whose data, title and legend are replaced between them:
    the same PNGs, pixel for pixel (tests/test_plots_fast.py), without building a figure, its
    axes and their ticks again for each (a third of a study's per-condition plotting,
    docs/performance.md)."""
    figures = list(figures)
    if not figures:
        return []
    with young_garbage():
        fig = _FrictionVsSpeed()
        return [fig.draw(*item) for item in figures]


class _FrictionVsSpeed:
    """The figure of :func:`plot_friction_vs_speed`: what every such figure shares (size,
    axis labels, margins) made once; :meth:`draw` adds one figure's data and saves it."""

    def __init__(self):
        self.fig = new_subplots(6.4, 4.4, dpi=110)
        ax = self.ax = self.fig.axes[0]
        ax.set_xlabel("link speed qd (rad/s)")
        ax.set_ylabel("friction torque (N m)")
        # one axes with known decorations: margins set once (tight_layout measured every text of
        # each of a study's per-trial figures: 14 s of its 34 s of plots, docs/performance.md)
        fixed_layout(self.fig, left_in=0.75, bottom_in=0.5, top_in=0.3)

    def _clear(self):
        """The axes as a new figure's: no lines, no legend, the colour cycle and the data
        limits from the start."""
        ax = self.ax
        for line in list(ax.lines):  # loop over the previous figure's few lines
            line.remove()
        if ax.get_legend() is not None:
            ax.get_legend().remove()
        ax.set_prop_cycle(None)
        ax.relim()
        ax.set_autoscale_on(True)

    def draw(self, path, qd, f_measured, models: dict, title: str) -> Path:
        """One figure: the measured friction, each model's curve, the zero lines, title and
        legend; saved as ``path``."""
        self._clear()
        ax = self.ax
        qd = np.asarray(qd, float)
        f = np.asarray(f_measured, float)
        ax.plot(qd, f, ".", ms=1.5, color="0.6", label="data", rasterized=True)
        lim = float(np.max(np.abs(qd))) if qd.size else 1.0
        v = np.linspace(-lim, lim, 801)
        for label, model in models.items():
            ax.plot(v, model.torque(v), lw=1.6, label=label)
        ax.axhline(0, color="0.85", lw=0.8)
        ax.axvline(0, color="0.85", lw=0.8)
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=8, loc="upper left")
        return save_png(self.fig, path, overwrite=True)
