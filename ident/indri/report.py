"""Reports of the Indri & Trapani 2020 framework (paper 001): the performance indices RMS, M, IN
of ``tau_res - tau_f`` and the relative errors Err% of Tables I-II, as CSV and Markdown; the
torque time histories of Figures 2, 4 and 5 (PNG and through a :class:`viz.sink.Sink`); the
per-joint report folder (:func:`write_report`)."""
from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ident.common import to_jsonable as _jsonable
from ident.friction import FrictionModel, LuGreDM1
from ident.friction.data import FrictionData
from ident.indri.estimator import IndriResult

__all__ = ["PI_NAMES", "performance_indices", "err_percent", "model_torque", "PerformanceTable",
           "performance_table", "damping_term", "figure_curves", "save_figures", "write_report"]

PI_NAMES = ("RMS", "M", "IN")


def performance_indices(tau_res, tau_f) -> dict:
    """Sec. V: RMS, mean (M, of the absolute value) and infinite norm (IN) of
    ``tau_diff = tau_res - tau_f``."""
    d = np.asarray(tau_res, float) - np.asarray(tau_f, float)
    return {"RMS": float(np.sqrt(np.mean(d ** 2))), "M": float(np.mean(np.abs(d))),
            "IN": float(np.max(np.abs(d)))}


def err_percent(pi_ref: float, pi_other: float) -> float:
    """Table I's relative percentage error of the reference model (DM2) against another:
    ``100 (PI_ref - PI_other) / PI_ref`` (negative: the reference is better)."""
    return 100.0 * (pi_ref - pi_other) / pi_ref if pi_ref != 0 else float("nan")


def model_torque(model: FrictionModel, data: FrictionData) -> np.ndarray:
    """Friction torque of ``model`` along ``data`` (dynamic models: eq. 29-30 on its steps)."""
    qd = np.asarray(data.qd, float)
    if model.dynamic:
        return model.torque(qd, np.asarray(data.qdd, float), data.dt)
    return model.torque(qd)


@dataclass(frozen=True)
class PerformanceTable:
    """Tables I-II: one row per (test, index) with each model's value and Err% of the reference
    model against every other one."""

    rows: tuple                   # ({"test", "PI", <model>: value, ..., "Err% <other>": ...}, ...)
    models: tuple                 # model names, reference first
    reference: str
    group: str = "Tests"

    @property
    def columns(self) -> tuple:
        return (self.group, "PI") + self.models + tuple(f"Err% {m}" for m in self.models[1:])

    def value(self, test: str, pi: str, model: str) -> float:
        for r in self.rows:
            if r["test"] == test and r["PI"] == pi:
                return r[model]
        raise KeyError((test, pi))

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.columns)
        for r in self.rows:
            w.writerow([r["test"], r["PI"]] + [f"{r[m]:.6g}" for m in self.models]
                       + [f"{r['Err% ' + m]:.1f}" for m in self.models[1:]])
        return buf.getvalue()

    def to_markdown(self, title: str | None = None) -> str:
        cols = self.columns
        lines = [] if title is None else [f"**{title}**", ""]
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|" + "|".join(["---"] * 2 + ["---:"] * (len(cols) - 2)) + "|")
        last = None
        for r in self.rows:
            name = r["test"] if r["test"] != last else ""
            last = r["test"]
            lines.append("| " + " | ".join([name, r["PI"]] + [f"{r[m]:.4g}" for m in self.models]
                                           + [f"{r['Err% ' + m]:.1f}" for m in self.models[1:]])
                         + " |")
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict:
        return _jsonable({"group": self.group, "reference": self.reference,
                          "models": list(self.models), "rows": [dict(r) for r in self.rows]})


def performance_table(models: dict, tests: dict, reference: str = "DM2",
                      group: str = "Tests") -> PerformanceTable:
    """Evaluate every model of ``models`` (name -> model, e.g. :attr:`IndriResult.models`) on
    every data set of ``tests`` (name -> :class:`FrictionData`) and lay out Table I (or Table II
    with ``group="Axis"``)."""
    if reference not in models:
        raise ValueError(f"reference model {reference!r} not among {list(models)}")
    names = (reference,) + tuple(m for m in models if m != reference)
    rows = []
    for tname, data in tests.items():
        pis = {m: performance_indices(data.tau, model_torque(models[m], data)) for m in names}
        for pi in PI_NAMES:
            row = {"test": tname, "PI": pi}
            row.update({m: pis[m][pi] for m in names})
            row.update({f"Err% {m}": err_percent(pis[reference][pi], pis[m][pi])
                        for m in names[1:]})
            rows.append(row)
    return PerformanceTable(rows=tuple(rows), models=names, reference=reference, group=group)


def damping_term(model, data: FrictionData) -> np.ndarray:
    """The ``f_sigma1(.) dz/dt`` term of eq. 6 along ``data`` (Figure 5): the torque minus the
    spring ``sigma0 z`` and the viscous part (eq. 9)."""
    qd = np.asarray(data.qd, float)
    z = model.states(qd, data.dt)
    return model_torque(model, data) - model.sigma0 * z - model.static.viscous(qd)


def figure_curves(result: IndriResult, data: FrictionData) -> dict:
    """The curves of Figures 2, 4 and 5 along ``data`` (e.g. :func:`figure1_knots`).

    Figure 2: friction with ``f_sigma1 = sigma1`` (constant), eq. 11 and eq. 12, sigma1 being
    the value identified at the lowest acceleration (phase 2-A), as in the paper. Figures 4/5:
    friction and damping term with eq. 11 and the largest / smallest phase 2-A sigma1, and with
    the identified eq. 24 (DM2). Returns ``{"fig2": {label: torque}, "fig4": ..., "fig5": ...}``.
    """
    st = result.static.model
    p2a = result.phase2a
    s0 = result.sigma0
    s_slow = p2a[result._slowest].sigma1
    s1s = [p.sigma1 for p in p2a]
    mk = {
        "constant sigma1": LuGreDM1(static=st, damping="constant", sigma0=s0, sigma1=s_slow),
        "eq. 11": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=s_slow),
        "eq. 12": LuGreDM1(static=st, damping="eq12", sigma0=s0, sigma1=s_slow),
    }
    mk4 = {
        "eq. 11, max sigma1": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=max(s1s)),
        "eq. 11, min sigma1": LuGreDM1(static=st, damping="eq11", sigma0=s0, sigma1=min(s1s)),
        "eq. 24 (DM2)": result.dm2,
    }
    return {"time": np.asarray(data.time, float), "qd": np.asarray(data.qd, float),
            "tau_res": np.asarray(data.tau, float),
            "fig2": {k: model_torque(m, data) for k, m in mk.items()},
            "fig4": {k: model_torque(m, data) for k, m in mk4.items()},
            "fig5": {k: damping_term(m, data) for k, m in mk4.items()}}


_FIG_TITLES = {"fig2": "Figure 2: friction torque with three bristle dampings",
               "fig4": "Figure 4: friction torque, eq. 11 (max/min sigma1) and eq. 24",
               "fig5": "Figure 5: damping term f_sigma1 dz/dt"}


def save_figures(curves: dict, out_dir, sink=None, prefix: str = "indri") -> dict:
    """Write Figures 2, 4 and 5 as PNG into ``out_dir`` (matplotlib, Agg) and log the same
    curves as scalar series to ``sink`` (a :class:`viz.sink.Sink`; rerun when enabled).
    Returns ``{"fig2": path, ...}``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = curves["time"]
    qd = curves["qd"]
    # the zoom (as in the paper's insets): around the fastest velocity reversal
    cross = np.flatnonzero(np.sign(qd[:-1]) * np.sign(qd[1:]) < 0)
    if cross.size:
        k = cross[int(np.argmax(np.abs(qd[cross + 1] - qd[cross])))]
        zoom = (t[k] - 0.05, t[k] + 0.15)
    else:
        zoom = (t[0], t[-1])
    zm = (t >= zoom[0]) & (t <= zoom[1])
    paths = {}
    for key in ("fig2", "fig4", "fig5"):
        fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 7.5),
                                            gridspec_kw={"height_ratios": [1, 3, 2]})
        ax0.plot(t, qd, color="0.3", lw=0.8)
        ax0.set_ylabel("qd [rad/s]")
        for ax, sel in ((ax1, slice(None)), (ax2, zm)):
            if key != "fig5":
                ax.plot(t[sel], curves["tau_res"][sel], color="0.75", lw=0.6,
                        label="residual torque")
            for lab, y in curves[key].items():
                ax.plot(t[sel], y[sel], lw=1.0, label=lab)
            ax.set_ylabel("torque [N m]")
        ax1.axvspan(*zoom, color="0.9", zorder=0)
        ax2.set_xlabel("time [s] (zoom on the fastest reversal)")
        ax1.legend(loc="upper left", fontsize=8)
        ax0.set_title(_FIG_TITLES[key], fontsize=10)
        fig.tight_layout()
        p = out_dir / f"{prefix}_{key}.png"
        fig.savefig(p, dpi=110)
        if sink is not None:
            fig.canvas.draw()
            sink.image(f"indri/{key}_plot", np.ascontiguousarray(
                np.asarray(fig.canvas.buffer_rgba())[..., :3]))
        plt.close(fig)
        paths[key] = p
        if sink is not None:
            names = list(curves[key])
            sink.scalars(f"indri/{key}", t, np.column_stack([curves[key][k] for k in names]),
                         names=names)
    if sink is not None:
        sink.scalars("indri/qd", t, curves["qd"])
        sink.scalars("indri/tau_res", t, curves["tau_res"])
    return paths


def write_report(result: IndriResult, out_dir, tables: dict | None = None,
                 curves: dict | None = None, sink=None) -> dict:
    """Write ``indri.json`` (the full result), ``phase2a.csv`` (Figure 3's sigma1 trend with
    the critical accelerations), each table of ``tables`` (name -> PerformanceTable) as
    ``<name>.csv`` and ``<name>.md``, and Figures 2/4/5 when ``curves`` are given. Returns the
    written paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    p = out / "indri.json"
    doc = {"format": 1, "result": result.to_dict()}
    if tables:
        doc["tables"] = {k: v.to_dict() for k, v in tables.items()}
    p.write_text(json.dumps(_jsonable(doc), indent=1))
    paths["json"] = p
    p = out / "phase2a.csv"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["label", "accel", "v_max", "sigma0", "sigma1", "sigma1_trend", "rms",
                "v_m", "critical_accel", "above_critical"])
    for f in result.phase2a:
        w.writerow([f.label, f"{f.accel:.6g}", f"{f.v_max:.6g}", f"{f.sigma0:.6g}",
                    f"{f.sigma1:.6g}", f"{result.sigma1_trend[0] / f.accel + result.sigma1_trend[1]:.6g}",
                    f"{f.fit.rms:.6g}", f"{f.v_m:.6g}", f"{f.critical_accel:.6g}",
                    int(f.above_critical)])
    p.write_text(buf.getvalue())
    paths["phase2a"] = p
    for name, tab in (tables or {}).items():
        (out / f"{name}.csv").write_text(tab.to_csv())
        (out / f"{name}.md").write_text(tab.to_markdown(title=name))
        paths[f"{name}.csv"] = out / f"{name}.csv"
        paths[f"{name}.md"] = out / f"{name}.md"
    if curves is not None:
        paths.update(save_figures(curves, out, sink=sink))
    if sink is not None and tables:
        sink.text("indri/tables", "\n".join(t.to_markdown(title=k) for k, t in tables.items()))
    return paths
