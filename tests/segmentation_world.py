"""Segmentations of one continuous multi-joint record (issue 14: "the verdict on a multi-joint
record does not change between any two reasonable segmentations").

* :func:`arm7_campaign` writes a FORMAT campaign of the hand-written 7-joint arm
  (``fixtures/arm7/arm7.urdf``) in which all joints move together: rigid-body torques from
  pinocchio's own ``rnea`` (per sample; no code shared with jointlab), Coulomb + viscous + offset
  per joint, and optionally, on one joint, a withheld effect written here in a form of its own:
  ``stribeck``, a friction drop at low speed of squared-secant shape ``Fs sgn(v) / cosh(v / vs)^2`` (outside
  the diagnosis's exponential and rational Stribeck families),
  or ``presliding``, a friction deficit after each velocity reversal that recovers
  hyperbolically with the displacement ``s`` since the reversal, ``-Fs sgn(v) s0 / (s0 + s)``;
  torque noise and encoder quantisation.
* :func:`resegment` rewrites a campaign whose one trial is a continuous record as the same record
  cut into several log files at arbitrary instants (a logger that rotates its files), or
  cropped at the start and the end; the manifest lists one multi-joint trial per file.
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ARM7 = REPO / "fixtures" / "arm7" / "arm7.urdf"

C_TRUE = np.array([3.0, 4.0, 2.0, 2.5, 0.8, 0.6, 0.3])      # Coulomb, N m
V_TRUE = np.array([6.0, 5.0, 3.0, 3.0, 1.0, 0.8, 0.4])      # viscous, N m s / rad
OFF_TRUE = np.array([0.3, -0.5, 0.2, 0.1, -0.05, 0.04, 0.02])
NOISE = np.array([0.2, 0.2, 0.15, 0.15, 0.05, 0.04, 0.03])


def arm7_campaign(root: Path, duration: float = 30.0, rate: float = 250.0, effect_joint: int | None = 2,
                  fs: float = 2.0, vs: float = 0.12, seed: int = 7, effect: str = "stribeck",
                  s0: float = 0.01) -> dict:
    """Write the campaign (``root/campaign.toml``, one trial ``rec``) and return its truth:
    ``effect`` (``stribeck`` or ``presliding``) on ``effect_joint`` (None: effect-free)."""
    import pinocchio as pin

    rng = np.random.default_rng(seed)
    model = pin.buildModelFromUrdf(str(ARM7))
    data = model.createData()
    n = model.nq
    t = np.arange(0.0, duration, 1.0 / rate)
    # sum of sines per joint around 0.4-0.9 Hz: a motion cycle every 1-2.5 s on every joint
    w = 2 * np.pi * rng.uniform(0.35, 0.9, (n, 3))
    a = rng.uniform(0.15, 0.35, (n, 3)) / np.array([1.0, 1.6, 2.4])
    ph = rng.uniform(0, 2 * np.pi, (n, 3))
    arg = t[:, None, None] * w[None] + ph[None]
    q = np.sum(a * np.sin(arg), axis=2)
    qd = np.sum(a * w * np.cos(arg), axis=2)
    qdd = -np.sum(a * w ** 2 * np.sin(arg), axis=2)
    tau = np.array([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(t.size)])
    tau += C_TRUE * np.sign(qd) + V_TRUE * qd + OFF_TRUE
    if effect_joint is not None and effect == "stribeck":
        v = qd[:, effect_joint - 1]
        tau[:, effect_joint - 1] += fs * np.sign(v) / np.cosh(v / vs) ** 2
    elif effect_joint is not None and effect == "presliding":
        x, v = q[:, effect_joint - 1], qd[:, effect_joint - 1]
        turn = np.r_[True, np.sign(v[1:]) != np.sign(v[:-1])]
        last = np.maximum.accumulate(np.where(turn, np.arange(t.size), 0))
        s = np.abs(x - x[last])                    # displacement since the last reversal
        tau[:, effect_joint - 1] += -fs * np.sign(v) * s0 / (s0 + s)
    elif effect_joint is not None:
        raise ValueError(f"unknown effect {effect!r}")
    tau += NOISE * rng.standard_normal(tau.shape)
    qm = np.round(q / 2e-5) * 2e-5
    root = Path(root)
    (root / "robot").mkdir(parents=True, exist_ok=True)
    (root / "trials").mkdir(exist_ok=True)
    (root / "robot" / "arm7.urdf").write_bytes(ARM7.read_bytes())
    (root / "robot" / "drives.toml").write_text("".join(
        f'[[joint]]\nname = "a{j}"\ngear_ratio = 100.0\n\n' for j in range(1, n + 1)), encoding="utf-8")
    names = ["time"] + [f"qm_{j}" for j in range(1, n + 1)] + [f"tau_{j}" for j in range(1, n + 1)]
    body = np.column_stack([t, qm, tau])
    np.savetxt(root / "trials" / "rec.csv", body, delimiter=",", header=",".join(names), comments="",
               fmt="%.9g")
    (root / "campaign.toml").write_text(
        'format = 1\nname = "arm7-segmentation"\n\n[robot]\nurdf = "robot/arm7.urdf"\n'
        'drives = "robot/drives.toml"\n\n[[trial]]\nid = "rec"\njoints = [1, 2, 3, 4, 5, 6, 7]\n'
        'kind = "excitation"\nlog = "trials/rec.csv"\n', encoding="utf-8")
    return {"t": t, "q": q, "qd": qd, "tau": tau, "effect_joint": effect_joint}


def resegment(src: Path, dst: Path, cuts=(), crop=(0.0, 0.0), lost: float = 0.0) -> Path:
    """Copy the campaign ``src`` (its manifest's first ``[[trial]]`` is one continuous record) to
    ``dst`` with that record cut at the fractions ``cuts`` of its rows (one log file and one
    ``[[trial]]`` per piece) after dropping ``crop = (s_start, s_end)`` seconds at its ends;
    ``lost`` seconds of samples are dropped after every cut (a logger that loses samples while
    it rotates its files: the pieces are then separate records). Everything before the first
    ``[[trial]]`` (robot, coupling) is kept."""
    src, dst = Path(src), Path(dst)
    man = (src / "campaign.toml").read_text(encoding="utf-8")
    head, trial = man.split("[[trial]]", 1)
    log = re.search(r'^log\s*=\s*"([^"]+)"', trial, re.M).group(1)
    joints = re.search(r"^joints\s*=\s*(\[[^\]]*\])", trial, re.M).group(1)
    lines = (src / log).read_text(encoding="utf-8").splitlines()
    header, rows = lines[0], lines[1:]
    tcol = np.array([float(r.split(",", 1)[0]) for r in rows])
    keep = np.flatnonzero((tcol >= tcol[0] + crop[0]) & (tcol <= tcol[-1] - crop[1]))
    rows = rows[keep[0]:keep[-1] + 1]
    edges = [0] + [int(round(c * len(rows))) for c in cuts] + [len(rows)]
    n_lost = int(round(lost / float(np.median(np.diff(tcol)))))
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.csv", "campaign.toml"))
    (dst / "trials").mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        name = f"trials/part-{k + 1}.csv"
        a = a if k == 0 else min(a + n_lost, b - 1)
        (dst / name).write_text("\n".join([header] + rows[a:b]) + "\n", encoding="utf-8")
        entries.append(f'[[trial]]\nid = "part-{k + 1}"\njoints = {joints}\nkind = "excitation"\n'
                       f'log = "{name}"\n')
    (dst / "campaign.toml").write_text(head + "\n".join(entries), encoding="utf-8")
    return dst


#: the segmentations measured: name -> (file cuts as fractions of the rows, crop (s, s),
#: seconds lost at each cut, n_segments)
SEGMENTATIONS = {
    "one file": ((), (0.0, 0.0), 0.0, None),
    "2 files": ((0.437,), (0.0, 0.0), 0.0, None),
    "3 files": ((0.291, 0.712), (0.0, 0.0), 0.0, None),
    "5 files": ((0.173, 0.389, 0.55, 0.801), (0.0, 0.0), 0.0, None),
    "3 files, 0.1 s lost": ((0.291, 0.712), (0.0, 0.0), 0.1, None),
    "5 files, 0.1 s lost": ((0.173, 0.389, 0.55, 0.801), (0.0, 0.0), 0.1, None),
    "crop 1.3 s / 0.7 s": ((), (1.3, 0.7), 0.0, None),
    "crop 0 s / 2.9 s": ((), (0.0, 2.9), 0.0, None),
    "n_segments 6": ((), (0.0, 0.0), 0.0, 6),
    "n_segments 10": ((), (0.0, 0.0), 0.0, 10),
    "n_segments 20": ((), (0.0, 0.0), 0.0, 20),
    "n_segments 40": ((), (0.0, 0.0), 0.0, 40),
}


def diagnose_segmentations(src: Path, work: Path, joints, names=None, seed: int = 0) -> dict:
    """``{segmentation: {joint: (verdict, held-out nominal RMS, n_blocks, verdict_status)}}``
    through the CLI's diagnosis of multi-joint records (``ident.cli.commands.diagnose._diagnose``,
    what ``jointlab diagnose CAMPAIGN`` runs; ``n_segments`` is not a CLI option, so those rows
    call :func:`ident.model.multijoint.diagnose_records` with it)."""
    from mocap.io.campaign import load_campaign

    from ident.cli.commands.diagnose import _diagnose
    from ident.gap import DiagnosisSettings
    from ident.model.multijoint import diagnose_records

    out = {}
    for name in (names or SEGMENTATIONS):
        cuts, crop, lost, nseg = SEGMENTATIONS[name]
        dst = resegment(src, Path(work) / re.sub(r"[^a-z0-9]+", "-", name.lower()), cuts, crop, lost)
        camp = load_campaign(dst)
        robot = camp.load_robot()
        st = DiagnosisSettings(seed=seed)
        if nseg is None:
            rep = _diagnose(camp, robot, None, st, list(joints))[0]["joints"]
        else:
            rep = diagnose_records(camp, robot, st, joints=list(joints), n_segments=nseg)[0]
        out[name] = {k: (r["verdict"], r["channels"]["torque"]["heldout_rms_nominal"],
                         r["channels"]["torque"].get("n_blocks"), r.get("verdict_status"))
                     for k, r in rep.items()}
    return out
