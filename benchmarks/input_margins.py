"""Margins of the plausibility checks (mocap/io/plausibility.py, docs/inputs.md) on campaigns
that must pass: for each campaign, the worst trial's figure next to the threshold it is held to.

    python benchmarks/input_margins.py fixtures/demo [MORE_CAMPAIGNS ...]
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def margins(root) -> dict:
    from ident.study.angles import campaign_references
    from mocap.io import plausibility as P
    from mocap.io.campaign import load_campaign
    from mocap.io.markers import read_markers

    c = load_campaign(root)
    r = c.load_robot()
    out = {"speed / (vmax_frac x max_velocity), min (refused < 1/900)": [],
           "p99 |tau| / max_torque, max (refused > 30)": [],
           "median |tau| / gravity torque, max (refused > 300)": [],
           "marker span / log span, min..max (refused outside 1/3..3)": [],
           "braked-link residual mm, max (refused > 50)": [],
           "moving-group residual mm, max (refused > 8 and 8 x noise)": []}
    refs = campaign_references(c, r, None)[0] if c.has_markers else None
    for t in c.trials:
        log = c.read_log(t, r)
        ok = np.flatnonzero(np.isfinite(log.qm).all(axis=1))
        pick = ok[np.linspace(0, ok.size - 1, min(200, ok.size)).astype(int)]
        G = np.array([np.atleast_1d(r.gravity_torque(q)) for q in log.qm[pick]])
        for j in t.joints:
            q = log.qm[:, j - 1]
            f = np.isfinite(q)
            v = P._p99(np.diff(q[f]) / np.diff(log.time[f]))
            vmax, tmax = r.drives[j - 1].max_velocity, r.drives[j - 1].max_torque
            if np.isfinite(vmax):               # an unknown limit: the check does not apply
                out["speed / (vmax_frac x max_velocity), min (refused < 1/900)"].append(
                    v / (t.vmax_frac * vmax))
            if np.isfinite(tmax):
                out["p99 |tau| / max_torque, max (refused > 30)"].append(P._p99(log.tau[:, j - 1]) / tmax)
            g = float(np.median(np.abs(G[:, j - 1])))
            if g >= 0.5:
                out["median |tau| / gravity torque, max (refused > 300)"].append(
                    float(np.median(np.abs(log.tau[pick, j - 1]))) / g)
        if t.markers is not None and refs is not None:
            m = read_markers(t.markers)
            out["marker span / log span, min..max (refused outside 1/3..3)"].append(
                (m.time[-1] - m.time[0]) / (log.time[-1] - log.time[0]))
            res, _ = P.braked_marker_residuals(m, log, refs, r, t)
            if len(res) >= 3:
                out["braked-link residual mm, max (refused > 50)"].append(1e3 * float(np.median(res)))
            rms, _ = P.moving_group_residual(m, log, refs, r, t)
            if np.isfinite(rms):
                out["moving-group residual mm, max (refused > 8 and 8 x noise)"].append(1e3 * rms)
    summary = {}
    for k, v in out.items():
        v = [x for x in v if np.isfinite(x)]
        if not v:
            continue
        summary[k] = (f"{min(v):.3g}..{max(v):.3g}" if "min..max" in k else
                      f"{(min(v) if ', min' in k else max(v)):.3g}")
    return summary


def main(argv=None) -> int:
    warnings.simplefilter("ignore")
    for root in (argv if argv is not None else sys.argv[1:]) or ["fixtures/demo"]:
        print(root)
        for k, v in margins(root).items():
            print(f"  {k}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
