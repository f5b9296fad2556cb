"""``sim2real.json``, ``sim2real.md`` (the models' held-out errors per joint and horizon) and plots
of measured against simulated trajectories."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ident.common import to_jsonable
from ident.sim2real.export import export_model

LABELS = {"given": "as given", "native": "native fit", "sysid": "mujoco.sysid",
          "native_effects": "native + named effects"}


def markdown(rep: dict) -> str:
    """The Markdown report: per horizon a table of held-out position / velocity RMS per joint."""
    models = [m for m in LABELS if m in rep["errors"]]
    lines = [f"# Sim-to-real in MuJoCo: {rep['campaign']}", "",
             f"Model: {rep['model']['source']} `{rep['model']['file']}`, integrator "
             f"{rep['model']['integrator']}. Train: {', '.join(rep['split']['train'])}; held out: "
             f"{', '.join(rep['split']['test'])} ({rep['split']['rule']}).", "",
             f"Effects ({rep['effects']['source']}): " + (", ".join(
                 f"joint {j}: {', '.join(v)}" for j, v in rep["effects"]["named"].items()) or "none named"), ""]
    for j, c in rep.get("effect_choice", {}).items():
        tr = c["training_rollout_rms"]
        lines.append(f"- joint {j} {c['effect']}: {'kept' if c['kept'] else 'dropped'} (training 0.5 s "
                     f"position RMS {tr['effect_free'] * 1e3:.3g} -> {tr['with_effect'] * 1e3:.3g} mrad)")
    if rep.get("unfitted_joints"):
        lines.append(f"- joints {', '.join(map(str, rep['unfitted_joints']))}: no training record moves "
                     "them by torque; the given native parameters kept")
    if rep.get("sysid"):
        lines.append(f"- mujoco.sysid: {rep['sysid'].get('status')}")
    lines.append("")
    for H in rep["horizons_s"]:
        key = f"{H:g}"
        lines += [f"## Horizon {key} s: held-out position RMS (mrad) / velocity RMS (mrad/s)", "",
                  "| joint | " + " | ".join(LABELS[m] for m in models) + " | effects / native |",
                  "|---|" + "---|" * (len(models) + 1)]
        for j in rep["scored_joints"]:
            cells, pos = [], {}
            for m in models:
                e = (rep["errors"][m].get(key) or {}).get(str(j))
                if e is None:
                    cells.append("-")
                    continue
                pos[m] = e["pos_rms"]
                cells.append(f"{e['pos_rms'] * 1e3:.3g} / {e['vel_rms'] * 1e3:.3g}")
            ratio = (f"{pos['native_effects'] / pos['native']:.2f}" if pos.get("native") and
                     "native_effects" in pos else "-")
            lines.append(f"| {j} | " + " | ".join(cells) + f" | {ratio} |")
        lines.append("")
    m = "native_effects" if "native_effects" in models else models[-1]
    lines += [f"## By motion regime ({LABELS[m]}, position RMS mrad, 0.5 s)", "",
              "| joint | low_speed | reversal | high_speed |", "|---|---|---|---|"]
    e5 = rep["errors"][m].get("0.5") or {}
    for j in rep["scored_joints"]:
        e = e5.get(str(j))
        if e:
            lines.append(f"| {j} | " + " | ".join(
                "-" if e["regimes"][r]["pos_rms"] is None else f"{e['regimes'][r]['pos_rms'] * 1e3:.3g}"
                for r in ("low_speed", "reversal", "high_speed")) + " |")
    lines += ["", f"Seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in rep["seconds"].items()), ""]
    return "\n".join(lines)


def plot(result, folder: Path, horizon: float = 2.0) -> list:
    """Per scored joint: measured angle against each model's simulation over the first held-out
    windows of ``horizon`` (``traj_joint<j>.png``)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rep = result.report
    rps = [(rp, m) for rp, m in zip(result.replayers, result.test_masks) if m.any()]
    if not rps:
        return []
    rp, mask = rps[0]
    starts = rp.windows(horizon, mask)[:3]
    if starts.size == 0:
        return []
    L = max(1, int(round(horizon / rp.rec.dt)))
    sims = {}
    for name in ("given", "native", "native_effects"):
        p = {k: np.asarray(v) for k, v in rep["parameters"][name].items()}
        sims[name] = rp.simulate(p, starts, L, result.effects if name == "native_effects" else None)[0]
    paths = []
    for j in rep["scored_joints"]:
        fig, ax = plt.subplots(figsize=(8, 3))
        for b, k0 in enumerate(starts):
            idx = np.arange(k0 + 1, k0 + L + 1)
            t = rp.rec.t[idx] - rp.rec.t[0]
            ax.plot(t, rp.rec.q[idx, j - 1], "k", lw=1.5, label="measured" if b == 0 else None)
            for name, st in (("given", ":"), ("native", "--"), ("native_effects", "-")):
                ax.plot(t, sims[name][b, :, j - 1], st, lw=1, label=LABELS[name] if b == 0 else None)
        ax.set_xlabel("time in record (s)")
        ax.set_ylabel(f"q{j} (rad)")
        ax.set_title(f"{rp.rec.trial_id}: joint {j}, {horizon:g} s windows from the measured state")
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = folder / f"traj_joint{j}.png"
        fig.savefig(p, dpi=90)
        plt.close(fig)
        paths.append(p)
    return paths


def write_report(result, folder: Path) -> dict:
    """``sim2real.json``, ``sim2real.md``, ``diagnosis.json`` (the diagnosis this run computed,
    for ``--diagnosis``), the plots and the export folder ``model/``."""

    folder = Path(folder)
    (folder / "sim2real.json").write_text(json.dumps(to_jsonable(result.report), indent=1))
    (folder / "sim2real.md").write_text(markdown(result.report))
    paths = {"json": folder / "sim2real.json", "md": folder / "sim2real.md"}
    if result.diagnosis is not None:       # reusable with --diagnosis
        (folder / "diagnosis.json").write_text(json.dumps(to_jsonable(result.diagnosis), indent=1))
        paths["diagnosis"] = folder / "diagnosis.json"
    paths["plots"] = plot(result, folder)
    paths["export"] = export_model(folder / "model", result)
    return paths
