"""Export of the corrected model: an MJCF with the fitted native parameters, the named effects as a
standalone passive-force callback module with its parameters in a JSON file, an example script,
and the held-out windows with jointlab's error for a check without jointlab.

Folder layout::

    model.xml                # the arm, fitted armature/damping/frictionloss, nuserdata for the effects
    sim2real_effects.py      # ident/sim2real/effects_runtime.py, verbatim (numpy + mujoco only)
    effects.json             # the effects' shapes and amplitudes per joint
    replay_example.py        # plain MuJoCo: load, install the callback, replay the held-out windows
    heldout/<trial>.xml      # the model with the record's payload
    heldout/<trial>.npz      # measured q, qd, torque, window starts, dof/qpos indices
    heldout/check.json       # jointlab's held-out position RMS per joint at each horizon
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from ident.sim2real import effects_runtime

EXAMPLE = '''"""Replay held-out windows of a record in plain MuJoCo with the corrected model exported by
``jointlab sim2real`` (no jointlab import): python replay_example.py [FOLDER]"""
import json
import sys
from pathlib import Path

import mujoco
import numpy as np

folder = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent)
sys.path.insert(0, str(folder))
import sim2real_effects as fx  # noqa: E402

params = json.loads((folder / "effects.json").read_text())
check = json.loads((folder / "heldout" / "check.json").read_text())
out = {}
for trial, by_h in check["trials"].items():
    m = mujoco.MjModel.from_xml_path(str(folder / "heldout" / f"{trial}.xml"))
    fx.install(m, params)                      # the effects as MuJoCo's passive-force callback
    d = mujoco.MjData(m)
    rec = np.load(folder / "heldout" / f"{trial}.npz")
    q, qd, tau, sub = rec["q"], rec["qd"], rec["tau"], int(rec["substeps"])
    dof, qadr, driven = rec["dof"], rec["qpos_adr"], rec["driven"].astype(bool)
    M, dt = int(rec["history_steps"]), float(rec["dt"])
    for H, entry in by_h.items():
        starts, L = rec[f"starts_{H}"], int(rec[f"L_{H}"])
        err = []
        for k0 in starts:
            mujoco.mj_resetData(m, d)
            d.qpos[qadr] = q[k0]
            d.qvel[dof] = qd[k0]
            hist = np.zeros((M, m.nv))               # measured velocities before the start
            hist[:, dof] = qd[np.maximum(k0 - M + np.arange(M), 0)]
            fx.reset(m, d, params, hist, dt)         # effects' state (presliding from the history)
            for i in range(L):
                d.ctrl[:len(dof)] = q[k0 + i]          # servo targets (zero gain on driven joints)
                d.qfrc_applied[:] = 0.0
                d.qfrc_applied[dof] = np.where(driven, tau[k0 + i], 0.0)
                for _ in range(sub):
                    mujoco.mj_step(m, d)
                err.append(d.qpos[qadr] - q[k0 + i + 1])
        rms = np.sqrt(np.mean(np.array(err) ** 2, axis=0))
        out.setdefault(trial, {})[H] = rms.tolist()
        print(trial, H, "s: position RMS per joint (mrad)", np.round(rms * 1e3, 3).tolist(),
              "jointlab:", np.round(np.array(entry["pos_rms"]) * 1e3, 3).tolist())
mujoco.set_mjcb_passive(None)
print(json.dumps(out))
'''


def export_model(folder, result, horizons=None, max_windows: int = 40) -> dict:
    """Write the export folder (module docstring) of a :class:`ident.sim2real.pipeline.Sim2RealResult`
    (its ``native_effects`` model); returns name -> path."""
    folder = Path(folder)
    (folder / "heldout").mkdir(parents=True, exist_ok=True)
    sm, doc, native = result.sim, result.effects, result.native
    nud = effects_runtime.nuserdata(sm.spec.copy().compile().nv)
    rps = result.replayers
    h0 = rps[0].h
    paths = {}
    spec = sm.spec_for(h0, None, native, nud)
    (folder / "model.xml").write_text(spec.to_xml())
    paths["mjcf"] = folder / "model.xml"
    shutil.copyfile(effects_runtime.__file__, folder / "sim2real_effects.py")
    paths["effects_module"] = folder / "sim2real_effects.py"
    (folder / "effects.json").write_text(json.dumps(doc, indent=1))
    paths["effects_json"] = folder / "effects.json"
    (folder / "replay_example.py").write_text(EXAMPLE)
    paths["example"] = folder / "replay_example.py"
    horizons = horizons or result.report["horizons_s"]
    check = {"model": "native_effects", "trials": {}}
    for rp, mask in zip(rps, result.test_masks):
        if not mask.any():
            continue
        rec = rp.rec
        spec = sm.spec_for(rp.h, rec.payload, native, nud)
        m = spec.compile()
        for k, (kp, kv) in enumerate(rp.gains):      # the servos of joints not driven by torque
            m.actuator_gainprm[k, 0] = kp
            m.actuator_biasprm[k, :3] = (0.0, -kp, -kv)
        xml = spec.to_xml()
        # gains written into the XML: position servos as general actuators
        import mujoco
        spec2 = mujoco.MjSpec.from_string(xml)
        for k, (kp, kv) in enumerate(rp.gains):
            a = spec2.actuator(f"jointlab_servo_{k + 1}")
            a.gainprm = [kp] + [0.0] * 9
            a.biasprm = [0.0, -kp, -kv] + [0.0] * 7
        (folder / "heldout" / f"{rec.trial_id}.xml").write_text(spec2.to_xml())
        arrays = {"q": rec.q, "qd": rec.qd, "tau": rec.tau, "substeps": rp.sub, "dof": sm.dof,
                  "qpos_adr": sm.qpos_adr, "driven": rec.driven, "dt": rec.dt,
                  "history_steps": rp.history_steps}
        entry = {}
        for H in horizons:
            key = f"{H:g}"
            res = rp.errors(native, H, mask, doc, max_windows)
            if res is None:
                continue
            eq, _, _, starts = res
            arrays[f"starts_{key}"] = starts
            arrays[f"L_{key}"] = max(1, int(round(H / rec.dt)))
            entry[key] = {"pos_rms": np.sqrt(np.mean(eq ** 2, axis=0)).tolist(), "windows": int(starts.size)}
        np.savez(folder / "heldout" / f"{rec.trial_id}.npz", **arrays)
        check["trials"][rec.trial_id] = entry
    (folder / "heldout" / "check.json").write_text(json.dumps(check, indent=1))
    paths["check"] = folder / "heldout" / "check.json"
    return paths
