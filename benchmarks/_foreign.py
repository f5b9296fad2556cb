"""The foreign world (../shared/worlds/foreign) as a test bed for the gap diagnosis.

Three things, none of which imports ``ident.gap`` (the diagnosis is only ever run through the
``jointlab diagnose`` command and read back from diagnosis.json):

- ``WorldArgs``: one make_world.py invocation, its cache name and command line;
- ``ensure_campaign``: generate a campaign once into a cache folder (atomic renames, so
  several processes may share the cache; INDEX.md gets one line per generated campaign);
- ``truth_reference``: the true-structure reference model built from the world's truth files
  (truth.json/.npz): the torque the diagnosis could at best explain, with the world's own
  signals and effect torque, fitted and cross-validated here (see its docstring).

Also ``score_diagnosis`` (verdict against the truth) shared by the benchmark and the CI test.
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

WORLD = Path(__file__).resolve().parents[2] / "shared" / "worlds" / "foreign"
DEFAULT_CACHE = Path.home() / ".cache" / "jointlab" / "foreign"   # or $JOINTLAB_CORPUS
EFFECTS = ("stribeck", "presliding", "position_ripple", "load_dependent", "thermal_drift",
           "compliance", "backlash", "torque_scale", "asymmetry", "nonlinear_viscous", "time_offset")
# effects that change the commanded torque (the others show in the motor-link deflection or
# in the marker clock only; the torque reference is not defined for them)
TORQUE_EFFECTS = ("stribeck", "presliding", "position_ripple", "load_dependent", "thermal_drift",
                  "torque_scale", "asymmetry", "nonlinear_viscous")
NOT_AN_ATTRIBUTION = ("none", "insufficient data")
DEFAULT_JOINT = {"ind6": 3, "tri3": 2}


def cache_dir() -> Path:
    return Path(os.environ.get("JOINTLAB_CORPUS", DEFAULT_CACHE))


@dataclass(frozen=True)
class WorldArgs:
    """One make_world.py invocation (defaults are the generator's)."""
    effect: str
    seed: int
    magnitude: float = 1.0
    robot: str = "ind6"
    joint: int | None = None
    second_effect: str | None = None
    reps: int = 4
    kinds: str = "excitation"
    noise: str = "white"
    payload_com_known: bool | str = True   # True, False (omitted: a wrong declaration) or "unknown"
    urdf_error: float = 0.0

    @property
    def moving_joint(self) -> int:
        return self.joint if self.joint is not None else DEFAULT_JOINT[self.robot]

    @property
    def name(self) -> str:
        """Cache name: robot-j<joint>-<effect>-m<mag>-s<seed> plus one suffix per non-default
        argument (the cache's naming scheme)."""
        s = f"{self.robot}-j{self.moving_joint}-{self.effect}-m{self.magnitude:g}-s{self.seed}"
        if self.second_effect:
            s += f"-x{self.second_effect}"
        if self.reps != 4:
            s += f"-r{self.reps}"
        if self.kinds != "excitation":
            s += "-k" + "".join(k[0] for k in self.kinds.split(","))
        if self.noise != "white":
            s += f"-n{self.noise}"
        if self.payload_com_known == "unknown":
            s += "-pcunknown"
        elif not self.payload_com_known:
            s += "-pcno"
        if self.urdf_error:
            s += f"-u{self.urdf_error:g}"
        return s

    def argv(self) -> list[str]:
        a = ["--seed", str(self.seed), "--effect", self.effect, "--magnitude", f"{self.magnitude:g}",
             "--robot", self.robot, "--joints", str(self.moving_joint)]
        if self.second_effect:
            a += ["--second-effect", self.second_effect]
        if self.reps != 4:
            a += ["--reps", str(self.reps)]
        if self.kinds != "excitation":
            a += ["--kinds", self.kinds]
        if self.noise != "white":
            a += ["--noise", self.noise]
        if self.payload_com_known == "unknown":
            a += ["--payload-com-known", "unknown"]
        elif not self.payload_com_known:
            a += ["--payload-com-known", "no"]
        if self.urdf_error:
            a += ["--urdf-error", f"{self.urdf_error:g}"]
        return a

    def matches(self, truth_args: dict) -> bool:
        """Whether a truth file's `arguments` are this invocation (guards cache names)."""
        j = truth_args.get("joints")
        joints = [int(x) for x in (j if isinstance(j, list) else str(j).split(","))]
        return (truth_args.get("effect") == self.effect and int(truth_args.get("seed")) == self.seed
                and abs(float(truth_args.get("magnitude")) - self.magnitude) < 1e-12
                and truth_args.get("robot") == self.robot and joints == [self.moving_joint]
                and (truth_args.get("second_effect") or None) == self.second_effect
                and int(truth_args.get("reps")) == self.reps and truth_args.get("kinds") == self.kinds
                and truth_args.get("noise") == self.noise
                and truth_args.get("payload_com_known") == {True: "yes", False: "no"}.get(
                    self.payload_com_known, self.payload_com_known)
                and abs(float(truth_args.get("urdf_error")) - self.urdf_error) < 1e-12)


def _complete(root: Path, name: str) -> bool:
    return ((root / name / "campaign.toml").is_file() and (root / f"{name}.truth.json").is_file()
            and (root / f"{name}.truth.npz").is_file())


def ensure_campaign(args: WorldArgs, root: Path | None = None, world: Path = WORLD,
                    nice: int = 10) -> tuple[Path, float]:
    """The campaign folder for `args` under `root` (generated when missing) and the seconds
    spent generating it (0 when cached). Generation goes to a private temporary folder and is
    renamed into place, so a half-written campaign is never visible."""
    root = Path(root) if root is not None else cache_dir()
    name = args.name
    if _complete(root, name):
        truth = json.loads((root / f"{name}.truth.json").read_text())
        if not args.matches(truth["arguments"]):
            raise RuntimeError(f"{root / name}: cached campaign was made with other arguments "
                               f"({truth['arguments']}); move it away")
        return root / name, 0.0
    import time

    if (root / name).exists():  # being written by someone else (or left half-done): wait
        for _ in range(120):
            time.sleep(10)
            if _complete(root, name):
                return ensure_campaign(args, root, world, nice)
        raise RuntimeError(f"{root / name} exists but is incomplete; remove it to regenerate")
    root.mkdir(parents=True, exist_ok=True)
    tmp = root / f".tmp-{name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    cmd = [sys.executable, str(world / "make_world.py"), str(tmp / name)] + args.argv()
    if nice:
        cmd = ["nice", "-n", str(nice)] + cmd
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if r.returncode != 0:
            raise RuntimeError(f"make_world.py {' '.join(args.argv())} failed (rc={r.returncode}): "
                               f"{(r.stderr or r.stdout).strip().splitlines()[-1:]}")
        gen_s = time.perf_counter() - t0
        if not _complete(root, name):  # another process may have finished it meanwhile
            for suf in (".truth.npz", ".truth.json"):
                os.replace(tmp / f"{name}{suf}", root / f"{name}{suf}")
            os.rename(tmp / name, root / name)
            _append_index(root, name, args, gen_s)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return root / name, gen_s


def _append_index(root: Path, name: str, args: WorldArgs, gen_s: float) -> None:
    """One row in root/INDEX.md (the corpus table: campaign, command, wall s, effect (form),
    trials, size), under the corpus lock."""
    truth = json.loads((root / f"{name}.truth.json").read_text())
    forms = ", ".join(f"{e['effect']} ({e['form']})" for e in truth["effects"])
    n_trials = sum(1 for it in truth["items_in_execution_order"] if it.get("section") == "trial")
    mb = lambda p: sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) / 2 ** 20  # noqa: E731
    row = (f"| {name} | `nice -n 10 python {WORLD}/make_world.py {root / name} {' '.join(args.argv())}` | "
           f"{gen_s:.1f} | {forms} | {n_trials} | {mb(root / name):.0f}M / "
           f"{(root / f'{name}.truth.npz').stat().st_size / 2 ** 20:.0f}M |\n")
    lock = root.parent / ".lock"
    with open(lock if os.access(root.parent, os.W_OK) else root / ".lock", "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        index = root / "INDEX.md"
        if not index.exists():
            index.write_text("# Foreign-world validation campaigns\n\n| campaign | command | wall s | "
                             "effect (form) drawn | trials | size (campaign dir / truth npz) |\n"
                             "|---|---|---:|---|---:|---|\n")
        with open(index, "a") as out:
            out.write(row)


# ---------------------------------------------------------------- truth-based reference

@dataclass(frozen=True)
class TruthReference:
    """Held-out torque RMS of the nominal model and of the true-structure model on one joint.

    Both models get the world's true rigid-body and drive torque (``tau_applied - friction``:
    rotor inertia, rotor viscous and transmitted spring torque, with the true masses), so the
    only free part is the friction: nominal = Coulomb (the world's tanh regularisation) +
    viscous, two fitted coefficients; true structure = nominal + the world's exact effect torque
    per sample (``friction - friction_nominal`` plus the torque-scale part
    ``tau_cmd - tau_applied``) with a fitted gain. Fitted by least squares on the moving samples
    of the logged torque (command + logged noise), held out trial by trial (leave-one-trial-out).
    ``reduction`` is 1 - rms_true/rms_nominal: the largest fraction of the held-out nominal RMS
    an effect model could remove (the rest is torque noise and command jitter)."""
    joint: int
    n_trials: int
    n_samples: int
    noise_rms: float             # RMS of the logged torque noise on the moving samples
    effect_rms: float            # RMS of the true effect torque on the moving samples
    rms_nominal: float
    rms_true: float
    reduction: float
    gain: float                  # fitted gain of the effect torque (1 = the truth)
    deflection_gap_rms_deg: float  # motor-link deflection not explained by the nominal spring
    marker_clock_error_rms_deg: float  # link-angle error from the marker clock offset/skew
    notes: tuple = field(default=())

    def to_dict(self) -> dict:
        return asdict(self)


def _moving_span(q_ref: np.ndarray) -> slice:
    moving = np.flatnonzero(np.abs(np.diff(q_ref)) > 0)
    if moving.size == 0:
        return slice(0, 0)
    return slice(int(moving[0]), int(moving[-1]) + 2)


def truth_reference(campaign: Path, joint: int | None = None, trial_ids=None,
                    truth_stem: Path | None = None, rigid_free: bool = False) -> TruthReference:
    """The reference for `campaign` (its truth files lie beside it, or at ``truth_stem`` +
    ``.truth.json/.npz``) on `joint` (default: the first moving joint), over ``trial_ids`` (default:
    every trial of the joint). With one trial the fit is not held out (leave-one-trial-out needs
    two): it is the in-sample reduction, which the true structure's one gain barely inflates.
    ``rigid_free``: both models also get free rigid-body corrections ``[qdd, sin q, cos q]`` of the
    link (what any estimator must fit when the URDF's inertial parameters are not exact): a torque
    gain on a record with one payload is then, rightly, not showable."""
    campaign = Path(campaign)
    stem = Path(truth_stem) if truth_stem is not None else campaign
    truth = json.loads(stem.with_name(stem.name + ".truth.json").read_text())
    a = truth["arguments"]
    if joint is None:
        j = a["joints"]
        joint = int(j[0] if isinstance(j, list) else str(j).split(",")[0])
    jt = next(x for x in truth["joints"] if int(x["joint"]) == joint)
    eps, k0, damping = jt["coulomb_regularisation_eps"], jt["stiffness"], jt["damping"]
    ids = [it["id"] for it in truth["items_in_execution_order"]
           if it.get("section") == "trial" and it.get("joint") == joint]
    if trial_ids is not None:
        ids = [i for i in ids if i in set(trial_ids)]
    npz = np.load(stem.with_name(stem.name + ".truth.npz"))
    X, y, e, noise, group, dgap, clock = [], [], [], [], [], [], []
    off, skew, t0 = (truth["clock"]["marker_offset_s"], truth["clock"]["marker_skew"],
                     truth["clock"]["campaign_start_s"])
    for g, tid in enumerate(ids):
        s = _moving_span(npz[f"{tid}/q_ref"])
        c = joint - 1
        qd = npz[f"{tid}/qd_motor"][s]
        fr, fr_nom = npz[f"{tid}/friction"][s], npz[f"{tid}/friction_nominal"][s]
        cmd, applied = npz[f"{tid}/tau_cmd"][s, c], npz[f"{tid}/tau_applied"][s]
        n = npz[f"{tid}/tau_noise"][s, c]
        rigid = applied - fr
        cols = [np.tanh(qd / eps), qd]
        if rigid_free:
            ql_, qdl_ = npz[f"{tid}/q_link"][s, c], npz[f"{tid}/qd_link"][s]
            cols += [np.gradient(qdl_, npz[f"{tid}/time"][s]), np.sin(ql_), np.cos(ql_)]
        X.append(np.column_stack(cols))
        y.append(cmd + n - rigid)
        e.append(fr - fr_nom + cmd - applied)
        noise.append(n)
        group.append(np.full(qd.shape[0], g))
        qm, ql = npz[f"{tid}/q_motor"][s, c], npz[f"{tid}/q_link"][s, c]
        qdl = npz[f"{tid}/qd_link"][s]
        dgap.append((qm - ql) - (npz[f"{tid}/spring_torque"][s] - damping * (qd - qdl)) / k0)
        t = npz[f"{tid}/time"][s]
        clock.append(qdl * (off + skew * (t - t0)))
    X, y, e, noise, group = (np.concatenate(v) for v in (X, y, e, noise, group))
    rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if v.size else float("nan")  # noqa: E731
    r_nom, _ = _loto_residual(X, y, group)
    r_true, gain = _loto_residual(np.column_stack([X, e]), y, group)
    rn, rt = rms(r_nom), rms(r_true)
    notes = () if {a["effect"], a.get("second_effect")} & set(TORQUE_EFFECTS + ("none",)) else (
        "effect does not act on the commanded torque: torque reduction not defined",)
    return TruthReference(joint=joint, n_trials=len(ids), n_samples=int(y.size), noise_rms=rms(noise),
                          effect_rms=rms(e), rms_nominal=rn, rms_true=rt,
                          reduction=float(1 - rt / rn) if rn > 0 else float("nan"), gain=float(gain),
                          deflection_gap_rms_deg=float(np.degrees(rms(np.concatenate(dgap)))),
                          marker_clock_error_rms_deg=float(np.degrees(rms(np.concatenate(clock)))),
                          notes=notes)


def _loto_residual(X: np.ndarray, y: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, float]:
    """Leave-one-group-out least-squares residuals (all groups at once from per-group normal
    equations) and the last column's coefficient of the fit on all data."""
    ng, p = int(group.max()) + 1, X.shape[1]
    if ng == 1:   # one group: in-sample
        scale = np.sqrt(np.mean(X ** 2, axis=0))
        scale[scale == 0] = 1.0
        th = np.linalg.lstsq(X / scale, y, rcond=None)[0]
        return y - (X / scale) @ th, float(th[-1] / scale[-1])
    scale = np.sqrt(np.mean(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    Xs = X / scale
    A = np.zeros((ng, p, p))
    b = np.zeros((ng, p))
    np.add.at(A, group, Xs[:, :, None] * Xs[:, None, :])
    np.add.at(b, group, Xs * y[:, None])
    At, bt = A.sum(0), b.sum(0)
    ridge = 1e-10 * np.trace(At) * np.eye(p)
    theta = np.linalg.solve(At - A + ridge, (bt - b)[:, :, None])[:, :, 0]  # ng x p
    resid = y - np.einsum("np,np->n", Xs, theta[group])
    full = np.linalg.solve(At + ridge, bt) / scale
    return resid, float(full[-1])


# ---------------------------------------------------------------- scoring

def ranked_effects(joint_report: dict) -> list[str]:
    """Effects in the order the diagnosis selected them: `selected` when the report has it,
    else its significant effects by decreasing reduction."""
    sel = joint_report.get("selected")
    if isinstance(sel, list) and all(isinstance(s, str) for s in sel):
        return list(sel)
    sig = [x for x in joint_report.get("effects", []) if x.get("significant")]
    sig.sort(key=lambda x: -(x.get("reduction") or 0.0))
    return [x["effect"] for x in sig]


def score_diagnosis(args: WorldArgs, report: dict) -> dict:
    """Verdict against the truth for the moving joint of one campaign."""
    jr = report["joints"][str(args.moving_joint)]
    verdict = jr["verdict"]
    ranked = ranked_effects(jr)
    red = {x["effect"]: x.get("reduction") for x in jr.get("effects", [])}
    rms = {x["effect"]: x.get("heldout_rms") for x in jr.get("effects", [])}
    out = {"verdict": verdict, "ranked": ranked, "heldout_rms_nominal": jr.get("heldout_rms_nominal"),
           "reduction_true_effect": red.get(args.effect), "reduction_verdict": red.get(verdict),
           "heldout_rms_true_effect": rms.get(args.effect)}
    alternatives = [a.get("effect") for a in jr.get("alternatives", [])]
    out["alternatives"] = alternatives
    if args.effect == "none":
        out["correct"] = verdict == "none"
        # a wrong payload declaration (COM omitted, FORMAT.md puts it at the flange origin) read
        # as a gain-like effect is not a false attribution when the report names the COM error
        out["false_attribution"] = verdict not in NOT_AN_ATTRIBUTION and not (
            args.payload_com_known is False and "payload_com" in alternatives)
    elif args.second_effect:
        out["correct"] = {args.effect, args.second_effect} <= set(ranked[:2])
        out["one_of_two"] = verdict in (args.effect, args.second_effect)
    else:
        out["correct"] = verdict == args.effect
    return out


def diagnose_in_process(campaign: Path, extra=(), clock=None) -> tuple:
    """``jointlab diagnose CAMPAIGN`` in this process, its output captured: (diagnosis.json as a
    dict or None, seconds by ``clock`` (default ``time.perf_counter``; ``time.process_time`` for
    CPU), error text or None). A crash or a non-zero exit is a benchmark result, not a stop."""
    import contextlib
    import io
    import tempfile
    import time

    from ident.cli.main import main as cli

    clock = clock or time.perf_counter
    with tempfile.TemporaryDirectory(prefix="jointlab-bench-diag-") as wd:
        out = Path(wd) / "out"
        t0 = clock()
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            try:
                rc = cli(["diagnose", str(campaign), "--out", str(out), *extra])
            except Exception as exc:  # noqa: BLE001 - a crash of the diagnosis is a result
                return None, clock() - t0, f"diagnose raised {type(exc).__name__}: {exc}"
        dt = clock() - t0
        if rc != 0:
            return None, dt, f"diagnose rc={rc}: {buf.getvalue().strip()[-300:]}"
        return json.loads((out / "diagnosis.json").read_text()), dt, None


def tile_log(log: Path, seconds: float) -> None:
    """Lengthen a log CSV (time in the first column) in place to ``seconds`` by repeating its rows,
    each repetition shifted by the log's span plus one sample step: a long record of the same
    motion for the speed benchmarks."""
    lines = log.read_text().splitlines()
    head, rows = lines[0], [ln.split(",", 1)[1] for ln in lines[1:]]
    t = np.array([float(ln.split(",", 1)[0]) for ln in lines[1:]])
    period = t[-1] - t[0] + float(np.median(np.diff(t)))
    reps = int(seconds // period) + 2
    tt = (t[None, :] + period * np.arange(reps)[:, None]).ravel()
    n = int(np.searchsorted(tt - t[0], seconds, side="right"))   # times increase: a prefix
    out = [head] + [f"{x:.6f},{rows[i % len(rows)]}" for i, x in enumerate(tt[:n])]
    log.write_text("\n".join(out) + "\n")
