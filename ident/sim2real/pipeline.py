"""The sim-to-real comparison of a campaign in MuJoCo: three models side by side on held-out data.

1. ``given``: the MuJoCo model as it comes (the user's MJCF, or the URDF compile with the drives'
   motor inertia and viscous friction);
2. ``native``: its MuJoCo-native joint parameters (armature, damping, frictionloss) fitted on the
   training data (:mod:`ident.sim2real.fit`); ``sysid``: the same parameters fitted by
   ``mujoco.sysid`` where it is installed (:mod:`ident.sim2real.sysid`);
3. ``native_effects``: the native parameters refitted together with the effects jointlab's gap
   diagnosis names per joint (``ident.workflow.diagnose_campaign``; ``effects`` overrides), run as
   an extra joint torque each step (:mod:`ident.sim2real.effects_runtime`).

Train/test split: with two or more records every second record (manifest order, the second, fourth,
...) is held out and the others train; a single record alternates time blocks of
:data:`BLOCK_S` seconds (at least an eighth of the record). Errors: :mod:`ident.sim2real.replay`.

Scored joints: those every record drives by its logged torque (none: an :class:`InputError`). A
joint without a moving training row of a record that drives it (a joint the trials hold, followed
through the servo) keeps the given model's native parameters (``unfitted_joints`` in
``sim2real.json``).
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError

from ident.sim2real import effects_runtime as fx
from ident.sim2real.fit import RANK_WINDOWS, Rollouts, TrainingSet, fit_effects, fit_native, refine
from ident.sim2real.model import NATIVE, build_model
from ident.sim2real.replay import HORIZONS, REGIMES, Replayer, records_of
from ident.workflow import diagnose_campaign
from ident.sim2real.model import captured_warnings
from ident.sim2real.sysid import fit_sysid

#: time block of the single-record split (s)
BLOCK_S = 4.0
MODELS = ("given", "native", "sysid", "native_effects")


def parse_effects(text: str | None, n: int) -> dict | None:
    """``--effects``: ``NAME`` (every joint) or ``J:NAME,J:NAME``; None: from the diagnosis."""
    if text is None:
        return None
    out = {}
    for item in (s.strip() for s in text.split(",") if s.strip()):
        j, _, nm = item.rpartition(":")
        if nm not in fx.EFFECTS and nm != "none":
            raise InputError(f"--effects: {nm!r} is not an effect the export implements "
                             f"({', '.join(fx.EFFECTS)}, or none)", label="--effects")
        joints = range(1, n + 1) if not j else [int(j)] if j.isdigit() and 1 <= int(j) <= n else None
        if joints is None:
            raise InputError(f"--effects: {j!r} is not a joint number 1..{n}", label="--effects")
        for jj in joints:
            if nm != "none":
                out[jj] = (nm,)
    return out


def split_masks(records, block_s: float = BLOCK_S) -> tuple:
    """(train, test) boolean sample masks per record (see the module docstring)."""
    train, test = [], []
    if len(records) >= 2:
        for i, r in enumerate(records):
            held = i % 2 == 1
            train.append(np.full(r.t.size, not held))
            test.append(np.full(r.t.size, held))
        return train, test
    r = records[0]
    dur = r.t[-1] - r.t[0]
    blk = max(block_s, dur / 8)
    b = np.floor((r.t - r.t[0]) / blk).astype(int)
    return [b % 2 == 0], [b % 2 == 1]


def _rms(x, m=None):
    if m is not None:
        x = x[m]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else None


@dataclass
class Sim2RealResult:
    """What :func:`sim2real_campaign` found: ``report`` (``sim2real.json``), the fitted parameters
    and effects, and the series for plots (model -> trial -> (starts, q_sim))."""

    report: dict
    native: dict
    effects: dict
    sim: object = None
    replayers: list = field(default_factory=list)
    test_masks: list = field(default_factory=list)
    diagnosis: dict | None = None      # the diagnosis report this run computed (diagnosis.json)


def evaluate(replayers, masks, native, effects=None, horizons=HORIZONS, max_windows=None) -> dict:
    """Held-out errors: horizon -> joint -> {pos_rms, vel_rms, n, regimes: {name: {...}}}; the
    scored joints are those every record drives by torque."""
    out = {}
    for H in horizons:
        eqs, evs, regs = [], [], {r: [] for r in REGIMES}
        for rp, m in zip(replayers, masks):
            res = rp.errors(native, H, m, effects, max_windows)
            if res is None:
                continue
            eq, ev, reg, _ = res
            keep = np.where(rp.rec.driven, 1.0, np.nan)
            eqs.append(eq * keep)
            evs.append(ev * keep)
            for r in REGIMES:
                regs[r].append(reg[r])
        if not eqs:
            out[f"{H:g}"] = None
            continue
        eq, ev = np.concatenate(eqs), np.concatenate(evs)
        reg = {r: np.concatenate(v) for r, v in regs.items()}
        per = {}
        for j in range(eq.shape[1]):
            if np.isnan(eq[:, j]).all():
                continue
            e = {"pos_rms": _rms(eq[:, j]), "vel_rms": _rms(ev[:, j]), "n_samples": int(eq.shape[0]),
                 "regimes": {}}
            for r in REGIMES:
                mk = reg[r][:, j]
                e["regimes"][r] = {"pos_rms": _rms(eq[:, j], mk), "vel_rms": _rms(ev[:, j], mk),
                                   "share": float(mk.mean())}
            per[str(j + 1)] = e
        out[f"{H:g}"] = per
    return out


def named_from_report(report: dict) -> tuple:
    """(joint -> (effect,), joint -> verdict): the effects a gap diagnosis report
    (``diagnosis.json``) names per joint that the export implements: the verdict, else the first
    selected effect."""
    verdicts, named = {}, {}
    for j, r in report["joints"].items():
        verdicts[int(j)] = r.get("verdict_text", r.get("verdict"))
        names = [s["effect"] for s in r.get("selected", []) if isinstance(s, dict) and s.get("effect") in fx.EFFECTS]
        v = r.get("verdict")
        if v in fx.EFFECTS and v not in names:
            names.insert(0, v)
        if names:
            named[int(j)] = tuple(names[:1])
    return named, verdicts


def diagnosed_effects(campaign, robot, progress=False) -> tuple:
    """(joint -> (effect,), joint -> verdict, report): the effects jointlab's gap diagnosis names
    (``ident.workflow.diagnose_campaign``, torque channel; :func:`named_from_report`) and its
    ``diagnosis.json`` document."""

    d = diagnose_campaign(campaign, robot=robot, markers=False, progress=progress)
    return (*named_from_report(d.report), d.report)


def read_diagnosis(path, campaign, n: int) -> dict:
    """An earlier ``diagnosis.json`` (``jointlab diagnose`` or ``jointlab sim2real``) of this
    campaign, checked: a JSON object whose ``campaign`` is this campaign's name and whose ``joints``
    are joint numbers 1..n, each with a ``verdict``. A mismatch is an :class:`InputError` naming the
    file and key."""
    path = Path(path)
    try:
        rep = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("diagnosis file not found", path=path) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"not a readable diagnosis.json ({e})", path=path) from None
    if not isinstance(rep, dict) or not isinstance(rep.get("joints"), dict):
        raise InputError("not a diagnosis.json: no 'joints' object", path=path, label="joints")
    if rep.get("campaign") != campaign.name:
        raise InputError(f"the diagnosis is of campaign {rep.get('campaign')!r}, not {campaign.name!r}",
                         path=path, label="campaign")
    for j, r in rep["joints"].items():
        if not (str(j).isdigit() and 1 <= int(j) <= n) or not isinstance(r, dict) or "verdict" not in r:
            raise InputError(f"joint {j!r}: not a joint 1..{n} with a verdict", path=path, label="joints")
    return rep


def sim2real_campaign(campaign, robot=None, **kw) -> Sim2RealResult:
    """:func:`_sim2real_campaign` with MuJoCo's warnings captured (none written to
    ``MUJOCO_LOG.TXT``): their count and first messages go to ``sim2real.json``
    (``simulation_warnings``)."""

    sink = []
    with captured_warnings(sink):
        res = _sim2real_campaign(campaign, robot, **kw)
    res.report["simulation_warnings"] = {"count": len(sink), "first": sorted(set(sink))[:5]}
    return res


def _sim2real_campaign(campaign, robot=None, *, mjcf=None, effects=None, diagnosis=None,
                       horizons=HORIZONS, sysid: bool = True, nthread: int = 1,
                       progress: bool = False) -> Sim2RealResult:
    """The three (four with ``mujoco.sysid``) models' held-out trajectory errors (module docstring).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        With multi-joint records (``joints = [1, ..., n]``) or a single joint's records.
    robot : mocap.robot.Robot, optional
    mjcf : path, optional
        The user's MJCF (default: ``[robot] mjcf``, else the URDF compile).
    effects : dict, optional
        joint -> (effect,) (:func:`parse_effects`); None: the diagnosis's named effects.
    diagnosis : dict, optional
        An earlier diagnosis report of the campaign (:func:`read_diagnosis`) whose named effects
        are used instead of running the diagnosis again (ignored with ``effects``).
    horizons : sequence of float
        Simulation horizons (s).
    sysid : bool
        Also fit with ``mujoco.sysid`` where it is installed.
    nthread : int
        ``mujoco.rollout`` threads.
    """
    t_all = time.perf_counter()
    robot = robot if robot is not None else campaign.load_robot()
    sm = build_model(campaign, robot, mjcf)
    records = records_of(campaign, robot)
    if not records:
        raise InputError("the campaign has no trials to replay", path=campaign.manifest)
    if not any(r.driven.any() for r in records):
        raise InputError("no record drives any joint by a logged torque (every moving joint is "
                         "unlogged_torque)", path=campaign.manifest)
    scored = [j for j in range(sm.n) if all(r.driven[j] for r in records)]
    if not scored:
        moving = "; ".join(f"{r.trial_id}: {', '.join(str(j + 1) for j in np.flatnonzero(r.driven)) or 'none'}"
                           for r in records)
        raise InputError("no joint is driven by its logged torque in every record, so none can be "
                         f"scored on held-out data (joints each trial drives: {moving})",
                         path=campaign.manifest)
    train, test = split_masks(records)
    rps = [Replayer(sm, robot, r, nthread) for r in records]
    timing = {}
    t0 = time.perf_counter()
    diag_report = None
    if effects is not None:
        named, verdicts, source = dict(effects), {}, "--effects"
    elif diagnosis is not None:
        named, verdicts = named_from_report(diagnosis)
        source = "diagnosis file"
    else:
        named, verdicts, diag_report = diagnosed_effects(campaign, robot, progress)
        source = "diagnosis"
    timing["diagnosis_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ts = TrainingSet(rps, train)
    # joints no training record drives (held at their logged angle by the servo) keep the given
    # model's parameters
    native, _, per_native = fit_native(ts, sm.n, None, robot.drives, start=sm.given)
    unfitted = [j for j in range(sm.n) if per_native[j + 1] is None]
    native_ls = {k: v.copy() for k, v in native.items()}
    ro = Rollouts(rps, train, nthread=nthread)
    native, _, base_rms = refine(ro, native, sm, scored)
    named = {j: v for j, v in named.items() if j - 1 in scored and j - 1 not in unfitted}
    native_fx, doc, choice = fit_effects(ts, ro, Rollouts(rps, train, RANK_WINDOWS, nthread), native,
                                         base_rms, named, sm, robot.drives)
    timing["fit_s"] = time.perf_counter() - t0
    models = {"given": (sm.given, None), "native": (native, None), "native_effects": (native_fx, doc)}
    sysid_info = None
    if sysid:
        t0 = time.perf_counter()
        sysid_info = fit_sysid(sm, rps, train, native_ls, nthread=nthread)
        timing["sysid_s"] = time.perf_counter() - t0
        if sysid_info.get("native") is not None:
            models["sysid"] = ({k: np.asarray(v) for k, v in sysid_info["native"].items()}, None)
    t0 = time.perf_counter()
    errors = {name: evaluate(rps, test, p, e, horizons) for name, (p, e) in models.items()}
    timing["evaluate_s"] = time.perf_counter() - t0
    timing["total_s"] = time.perf_counter() - t_all
    tid = [r.trial_id for r in records]
    report = {
        "format": 1, "campaign": campaign.name,
        "model": {"source": sm.source, "file": sm.path.name, "joints": list(sm.names),
                  "timestep_s": {r.trial_id: rp.h for r, rp in zip(records, rps)},
                  "integrator": "implicitfast", "notes": list(sm.notes)},
        "split": {"train": [t for t, m in zip(tid, train) if m.any()],
                  "test": [t for t, m in zip(tid, test) if m.any()],
                  "rule": ("every second record held out" if len(records) >= 2 else
                           "alternate time blocks of one record")},
        "scored_joints": [j + 1 for j in scored],
        "unfitted_joints": [j + 1 for j in unfitted],
        "effects": {"source": source, "named": {str(j): list(v) for j, v in sorted(named.items())},
                    "diagnosis_verdicts": {str(j): v for j, v in sorted(verdicts.items())}},
        "parameters": {name: {k: [float(x) for x in v[k]] for k in NATIVE} for name, (v, _) in models.items()},
        "effect_parameters": doc,
        "effect_choice": {str(j): v for j, v in choice.items()},
        "sysid": sysid_info and {k: v for k, v in sysid_info.items() if k != "native"},
        "horizons_s": [float(h) for h in horizons],
        "errors": errors,
        "seconds": timing,
    }
    return Sim2RealResult(report, native_fx, doc, sm, rps, test, diag_report)
