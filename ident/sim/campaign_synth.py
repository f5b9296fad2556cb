"""The simulated world: write a FORMAT v1 campaign of the (simulated) PA10 with one withheld
effect, and its ground truth beside it (``<prefix>.truth.json`` + ``<prefix>.truth.npz``),
never inside the campaign.

A campaign holds a static pose (2 s still), calibration sweeps of joint 1 then joint 2 alone
(+-60 deg), and trials: for each kind, joint, load, speed fraction and repetition one
recording. All recordings share one controller clock (trials follow each other with pauses,
so thermal drift shows); marker files run at their own rate and start/stop at other times.

The nominal plant is the flexible joint at the stiffness the robot's drives.toml declares (the
bundled PA10: 40000, 40000, 25000, 5000, 5000, 5000 N m/rad; a joint without a declared
stiffness is simulated rigid-equivalent and stays undeclared, see
:func:`ident.sim.effects.nominal_stiffness`), well damped, with the thesis's Coulomb + viscous
friction per joint (Tables 5-1, A-1..A-9, no load, fastest range); the controller's
feed-forward uses the same declared stiffness; the effect is added on the joints under study
(see :mod:`ident.sim.effects`; ``compliance`` is softer than declared).
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import shutil
import zipfile
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mocap.io.errors import InputError

from ident.sim.effects import Effect, nominal_stiffness, truth_models
from ident.sim.plant import (Controller, JointPlant, rest_state, simulate_coastdown, simulate_multi,
                  simulate_single)
from ident.excitation.trajectories import (constant_velocity, fourier_excitation, min_jerk_path,
                                           reversals)
from mocap.io.campaign import write_manifest
from mocap.io.robotlog import RobotLog
from mocap.io.trc import write_trc
from mocap.kinematics import invert_transform
from mocap.robot import Robot
from mocap.synth import MarkerErrors, place_markers, random_camera_pose, synthesize_recording
from mocap.urdf import load_link_meshes, perturb_urdf
from viz.sink import NullSink

REPO = Path(__file__).resolve().parents[2]
PA10_DIR = REPO / "fixtures" / "robots" / "pa10"

#: thesis Coulomb + viscous per joint (c N m, v N m s/rad), no load, fastest speed range:
#: Tables A-1 (j1), A-3 (j2), A-5 (j3), A-7 (j4), 5-1 (j5), A-9 (j6)
PA10_CV = {1: (9.53, 5.62), 2: (13.39, 24.01), 3: (8.34, 5.20), 4: (1.51, 0.36),
           5: (3.90, 0.84), 6: (1.20, 0.30)}

#: pose of the held joints (rad): elbow bent, wrist pitched, non-singular
REST_POSE = (0.0, 0.35, 1.3, 0.0, 0.6, 0.0)
STATIC_POSE = (0.4, 0.3, 1.2, 0.5, 0.8, 0.3)
KIND_TAG = {"excitation": "", "reversals": "rev-", "constant_velocity": "cvel-", "coastdown": "cd-"}
PAUSE_S = 4.0


@dataclass(frozen=True)
class SynthConfig:
    """Settings of ``jointlab synth`` (one campaign)."""

    joints: tuple[int, ...] = (5,)
    loads: tuple[float, ...] = (0.0, 3.373)
    vmax: tuple[float, ...] = (0.3, 0.6, 1.0)
    reps: int = 5
    duration: float = 20.0
    kinds: tuple[str, ...] = ("excitation",)
    robot: str = "pa10"
    effect: str = "none"
    magnitude: float = 1.0
    seed: int = 0
    marker_rate: float = 100.0
    log_rate: float = 200.0
    sim_rate: float = 2000.0
    label_swaps: int = 0
    together: bool = False
    markers_per_link: tuple[int, int] = (3, 4)
    torque_noise: float | None = None   # N m; default 0.05 + 0.002 max_torque per joint
    payload_offset: tuple[float, float, float] = (0.0, 0.0, 0.05)
    name: str = ""
    extra: dict = field(default_factory=dict)

    def validate(self, n_joints: int = 6) -> None:
        for j in self.joints:
            if not 1 <= j <= n_joints:
                raise InputError(f"--joints: joint {j} is not in 1..{n_joints}")
        for k in self.kinds:
            if k not in KIND_TAG:
                raise InputError(f"--kinds: {k!r} is not one of {', '.join(KIND_TAG)}")
        if any(v <= 0 or v > 1.0 for v in self.vmax):
            raise InputError("--vmax: speed fractions must be in (0, 1]")
        if any(m < 0 for m in self.loads):
            raise InputError("--loads: loads are masses in kg, >= 0")
        if self.reps < 1:
            raise InputError("--reps must be >= 1")
        if self.duration < 2.0:
            raise InputError("--duration must be at least 2 s")
        if self.together and (len(self.joints) < 2 or set(self.kinds) != {"excitation"}):
            raise InputError("--together needs two or more --joints and --kinds excitation")
        lo, hi = self.markers_per_link
        if not 3 <= lo <= hi <= 8:
            raise InputError("--markers-per-link: need 3 <= min <= max <= 8 (3 or more per link)")
        if self.robot not in ("pa10", "perturbed"):
            raise InputError("--robot must be pa10 or perturbed")
        if self.log_rate <= 0 or self.marker_rate <= 0 or self.sim_rate < 2000:
            raise InputError("rates must be positive and the simulation rate >= 2000 Hz")
        Effect(self.effect, self.magnitude)


def trial_id(kind: str, joint: int, load: float, vf: float, rep: int) -> str:
    return f"j{joint}-{KIND_TAG[kind]}load{int(load * 10 + 1e-9)}-v{int(round(vf * 100))}-r{rep}"


@dataclass(frozen=True)
class _Plan:
    kind: str          # static | calib | trial kinds
    id: str
    joint: int         # 1-based moving joint (0: none)
    load: float
    vf: float
    rep: int
    ref: object        # reference trajectory (None for coastdown/static)
    q_rest: tuple
    duration: float
    rel: str           # path stem relative to the campaign
    together: tuple = ()   # several moving joints (1-based) for a multi-joint trial

    @property
    def joints(self) -> tuple:
        return self.together or ((self.joint,) if self.joint else ())


def _seq(*ints) -> np.random.Generator:
    return np.random.default_rng([int(i) for i in ints])


def _write_npz(path: Path, arrays: dict) -> None:
    """A .npz with fixed zip timestamps (byte-identical for identical arrays)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key in arrays:
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arrays[key]), allow_pickle=False)
            zi = zipfile.ZipInfo(key + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            zi.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(zi, buf.getvalue())


def _copy_robot(dst_dir: Path, src_dir: Path) -> tuple[Path, Path]:
    dst_dir.mkdir(parents=True, exist_ok=True)
    urdf = dst_dir / "arm.urdf"
    shutil.copyfile(src_dir / "pa10.urdf", urdf)
    shutil.copyfile(src_dir / "drives.toml", dst_dir / "drives.toml")
    if (src_dir / "meshes").is_dir():
        shutil.copytree(src_dir / "meshes", dst_dir / "meshes", dirs_exist_ok=True)
    return urdf, dst_dir / "drives.toml"


def _link_meshes(urdf: Path, robot) -> dict:
    """Link meshes from the URDF (mocap.urdf), else capsules along each link."""
    meshes = {}
    try:
        meshes = load_link_meshes(urdf)
    except (ImportError, InputError, ValueError, OSError):
        meshes = {}
    import trimesh

    chain = robot.chain
    for k in range(robot.n):
        link = robot.link_of_joint(k)
        if link in meshes:
            continue
        nxt = chain.T_parent_joint[k + 1][:3, 3] if k + 1 < robot.n else np.array([0, 0, 0.07])
        ln = max(float(np.linalg.norm(nxt)), 0.05)
        cap = trimesh.creation.capsule(height=ln, radius=0.05, count=[12, 12])
        cap.apply_translation([0, 0, ln / 2])
        meshes[link] = (np.asarray(cap.vertices), np.asarray(cap.faces))
    return meshes


class CampaignSynth:
    """Plans, simulates and writes one campaign (settings in the constructor, work in
    :meth:`write`)."""

    def __init__(self, cfg: SynthConfig, robot_dir: Path = PA10_DIR):
        self.cfg = cfg
        self.robot_dir = Path(robot_dir)
        if not (self.robot_dir / "pa10.urdf").is_file():
            raise InputError("bundled robot description not found", path=self.robot_dir / "pa10.urdf")

    # ---------------------------------------------------------------------------------------
    def _robots(self, work: Path):
        nominal = Robot.from_urdf(self.robot_dir / "pa10.urdf", self.robot_dir / "drives.toml")
        cfg = self.cfg
        cfg.validate(nominal.n)
        truth_urdf = self.robot_dir / "pa10.urdf"
        perturbation = None
        if cfg.robot == "perturbed":
            truth_urdf = work
            perturb_urdf(self.robot_dir / "pa10.urdf", work, seed=cfg.seed, overwrite=True)
            perturbation = {"seed": cfg.seed, "function": "mocap.urdf.perturb_urdf"}
            actual = Robot.from_urdf(work, self.robot_dir / "drives.toml")
        else:
            actual = nominal
        return nominal, actual, truth_urdf, perturbation

    def _plan(self, robot) -> list[_Plan]:
        cfg = self.cfg

        plans = [_Plan("static", "static-1", 0, 0.0, 0.0, 0, None, STATIC_POSE, 2.0 + 0.6,
                       "static/pose-01")]
        for j in (1, 2):
            k = j - 1
            c0 = REST_POSE[k]
            lo, hi = robot.lower[k] + 0.05, robot.upper[k] - 0.05
            a, b = max(c0 - math.radians(60), lo), min(c0 + math.radians(60), hi)
            ref = min_jerk_path([c0, b, a], robot.max_velocity[k], 3.0, hold=0.5)
            plans.append(_Plan("calib", f"calib-joint-{j}", j, 0.0, 0.3, 0, ref, REST_POSE,
                               ref.duration, f"calib/joint-{j}"))
        def span(j):
            k = j - 1
            lo, hi = float(robot.lower[k]), float(robot.upper[k])
            centre = float(np.clip(REST_POSE[k], lo + 0.3, hi - 0.3))
            return centre, float(min(1.2, 0.8 * min(centre - lo, hi - centre)))

        if cfg.together:
            js = tuple(cfg.joints)
            for load in cfg.loads:
                for vi, vf in enumerate(cfg.vmax):
                    refs = [fourier_excitation(_seq(cfg.seed, 12, j, vi), float(robot.max_velocity[j - 1]),
                                               vf, cfg.duration, *span(j)) for j in js]
                    for rep in range(1, cfg.reps + 1):
                        tid = f"j{''.join(str(j) for j in js)}-load{int(load * 10 + 1e-9)}" \
                              f"-v{int(round(vf * 100))}-r{rep}"
                        plans.append(_Plan("excitation", tid, js[0], load, vf, rep, refs, REST_POSE,
                                           max(r.duration for r in refs), f"trials/{tid}", js))
            return plans
        for kind in cfg.kinds:
            for j in cfg.joints:
                k = j - 1
                vmax = float(robot.max_velocity[k])
                centre, half = span(j)
                for load in cfg.loads:
                    for vi, vf in enumerate(cfg.vmax):
                        if kind == "excitation":
                            ref = fourier_excitation(_seq(cfg.seed, 11, j, vi), vmax, vf, cfg.duration,
                                                     centre, half)
                        elif kind == "reversals":
                            ref = reversals(vmax, vf, centre, half)
                        elif kind == "constant_velocity":
                            ref = constant_velocity(vmax, vf, centre, half)
                        else:
                            ref = {"centre": centre, "half": half, "vmax": vmax}
                        dur = ref.duration if kind != "coastdown" else _coast_duration()
                        for rep in range(1, cfg.reps + 1):
                            tid = trial_id(kind, j, load, vf, rep)
                            plans.append(_Plan(kind, tid, j, load, vf, rep, ref, REST_POSE, dur,
                                               f"trials/{tid}"))
        return plans

    # ---------------------------------------------------------------------------------------
    def write(self, out: Path, truth_prefix: Path | None = None, overwrite: bool = False,
              progress: bool = True, sink=None, command: str = "", regenerate: str = "") -> dict:
        """Simulate and write the campaign to ``out`` and the truth to ``truth_prefix``
        (default: ``out`` itself, giving ``OUT.truth.json`` beside the folder). ``regenerate``
        (the exact command line) goes into ``OUT/REGENERATE.md``. Returns a summary dict."""
        sink = sink or NullSink()
        cfg = self.cfg
        out = Path(out)
        truth_prefix = Path(truth_prefix) if truth_prefix is not None else out
        truth_json = truth_prefix.parent / (truth_prefix.name + ".truth.json")
        truth_npz = truth_prefix.parent / (truth_prefix.name + ".truth.npz")
        cfg.validate()
        if out.exists() and any(out.iterdir()):
            if not overwrite:
                raise FileExistsError(f"{out} exists and is not empty; pass --overwrite to replace it")
            if not (out / "campaign.toml").is_file():
                raise InputError("--overwrite replaces campaign folders only, and this folder has no "
                                 "campaign.toml; choose another folder", path=out)
        if out.resolve() in truth_json.resolve().parents:
            raise InputError("the truth files must not be inside the campaign folder", path=truth_json)
        if out.exists() and overwrite:
            shutil.rmtree(out)
        out.mkdir(parents=True)
        truth_json.parent.mkdir(parents=True, exist_ok=True)
        urdf, _ = _copy_robot(out / "robot", self.robot_dir)
        pert_path = truth_prefix.parent / (truth_prefix.name + ".truth.urdf")
        nominal, actual, _, perturbation = self._robots(pert_path)
        plans = self._plan(nominal)

        rng_m = _seq(cfg.seed, 7)
        link_names = [nominal.link_of_joint(k) for k in range(nominal.n)]
        meshes = _link_meshes(urdf, nominal)
        markers = place_markers(meshes, link_names, rng_m, per_link=cfg.markers_per_link)
        T_camera_base = random_camera_pose(_seq(cfg.seed, 8))
        errors = MarkerErrors(label_swaps=cfg.label_swaps)
        self._meshes = meshes
        if sink.enabled:
            sink.transform("world/camera", invert_transform(T_camera_base))
            sink.text("synth/README", f"simulated campaign `{out.name}`: effect **{cfg.effect}** "
                                      f"M = {cfg.magnitude:g}, seed {cfg.seed}; true link angle vs "
                                      "measured motor angle, true vs measured torque, markers "
                                      "(camera frame) and the robot (link angles) over the "
                                      "campaign clock.")

        # campaign clock
        clock0 = 1000.0 + float(_seq(cfg.seed, 9).integers(0, 1000))
        campaign_length = sum(p.duration + PAUSE_S for p in plans)  # planned (thermal time scale)
        effect = Effect(cfg.effect, cfg.magnitude)

        payload_robots = {}
        nominal_payload = {}

        def robots_for(load):
            if load not in payload_robots:
                payload_robots[load] = actual.with_payload(load, cfg.payload_offset)
                nominal_payload[load] = nominal.with_payload(load, cfg.payload_offset)
            return payload_robots[load], nominal_payload[load]

        joint_truth = {}
        k0 = {}                      # nominal (declared) stiffness per joint, N m/rad
        self._k0 = k0
        for j in range(1, nominal.n + 1):
            c, v = PA10_CV[j]
            dr = nominal.drives[j - 1]
            studied = j in cfg.joints
            eff = effect if studied else Effect("none", 0.0)
            # inertia used only for the damping constants: link at rest pose + motor
            Mrest = nominal.mass_matrix(np.array(REST_POSE))
            k0[j] = nominal_stiffness(dr)
            fx = eff.joint_params(c, v, dr.max_torque, dr.max_velocity,
                                  float(Mrest[j - 1, j - 1]) + dr.motor_inertia, campaign_length, k0[j])
            joint_truth[j] = fx

        manifest = {"format": 1, "name": cfg.name or out.name,
                    "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml",
                              "gravity": [0.0, 0.0, -9.81]},
                    "markers": markers.by_link(), "static": [], "calib": [], "trial": []}
        truth_trials = {}
        arrays = {}
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(plans), desc="synth", unit="rec", leave=False)
        dt = 1.0 / cfg.sim_rate
        t0 = clock0
        for pi, p in enumerate(plans):
            rng = _seq(cfg.seed, 1000 + pi)
            rec_truth = self._simulate(p, t0, dt, nominal, robots_for, joint_truth, clock0,
                                       rng, markers, T_camera_base, errors, out, arrays, sink)
            truth_trials[p.id] = rec_truth
            entry = {"markers": p.rel + ".trc", "log": p.rel + ".csv"}
            if p.kind == "static":
                manifest["static"].append(entry)
            elif p.kind == "calib":
                manifest["calib"].append({"joint": p.joint, **entry})
            else:
                manifest["trial"].append({"id": p.id, "joints": list(p.joints), "load_kg": p.load,
                                          "vmax_frac": p.vf, "repetition": p.rep, "kind": p.kind,
                                          **entry,
                                          # extra key (kept by readers): payload centre of mass
                                          # in the flange (last link) frame, m
                                          "payload_com": [float(x) for x in cfg.payload_offset]})
            t0 = rec_truth["t_end"] + PAUSE_S
            if bar is not None:
                bar.update(1)
        clock_end = t0 - PAUSE_S
        if bar is not None:
            bar.close()
        write_manifest(out / "campaign.toml", manifest, overwrite=True)
        if regenerate:
            (out / "REGENERATE.md").write_text(
                "# How this campaign was made\n\nA simulated campaign (FORMAT v1) written by "
                "`jointlab synth`. Regenerate it byte for byte, from the folder it was made in (the "
                "repository root for fixtures/demo), with\n\n```\n"
                f"{regenerate} --overwrite\n```\n\nThe ground truth (true link angles, friction, "
                "effect parameters, camera pose, marker positions in the link frames) is written beside "
                "the campaign, never inside it: `" + truth_json.name + "` and `" + truth_npz.name + "`.\n",
                encoding="utf-8")

        truth = {
            "format": 1,
            "seed": cfg.seed,
            "command": command,
            "config": _jsonable(asdict(cfg)),
            "robot": {"campaign_urdf": "robot/arm.urdf", "bundled": str(self.robot_dir.relative_to(REPO))
                      if REPO in self.robot_dir.parents else str(self.robot_dir),
                      "simulated_urdf": (pert_path.name if perturbation else "campaign robot/arm.urdf"),
                      "perturbation": perturbation},
            "effect": effect.to_dict(),
            "joints": {str(j): {"studied": j in cfg.joints, "nominal": {"cv": {"c": PA10_CV[j][0],
                                                                               "v": PA10_CV[j][1]}},
                                "true_models": truth_models(fx), "plant": fx.to_dict(),
                                "k_nominal": k0[j],
                                "k_declared": "stiffness" in nominal.drives[j - 1].extra,
                                "J": nominal.drives[j - 1].motor_inertia,
                                "B": nominal.drives[j - 1].motor_viscous}
                       for j, fx in joint_truth.items()},
            "clock": {"start": clock0, "end": clock_end, "planned_length_s": campaign_length},
            "T_camera_base": np.asarray(T_camera_base).tolist(),
            "markers": markers.to_dict(),
            "marker_noise_rms_m": errors.noise_rms,
            "trials": truth_trials,
            "npz_keys": "<recording id>/<signal>: time, q, qd, qdd, qm, qmd, f, u, tau_t, "
                        "q_ref at the log rate, link side, SI; (T,) for one moving joint, (T, m) "
                        "for several; qdd is the mean over one log interval",
        }
        _write_npz(truth_npz, arrays)
        truth_json.write_text(json.dumps(truth, indent=1, sort_keys=False) + "\n", encoding="utf-8")
        return {"out": str(out), "truth": str(truth_json), "recordings": len(plans),
                "campaign_seconds": clock_end - clock0}

    # ---------------------------------------------------------------------------------------
    def _simulate(self, p: _Plan, t0, dt, nominal, robots_for, joint_truth, clock0, rng, markers,
                  T_camera_base, errors, out, arrays, sink) -> dict:
        cfg = self.cfg
        n = nominal.n
        rest = np.array(p.q_rest if p.kind != "static" else STATIC_POSE, float)
        actual, nom = robots_for(p.load)
        info = {"kind": p.kind, "joint": p.joint, "joints": list(p.joints), "load_kg": p.load,
                "vmax_frac": p.vf,
                "repetition": p.rep, "t_start": t0, "q_rest": rest.tolist(),
                "markers": p.rel + ".trc", "log": p.rel + ".csv"}
        mode = None
        moving = [j - 1 for j in p.joints]          # 0-based moving joints
        sig_full = None                             # name -> (N, m) full-rate signals
        if not moving:
            N = int(round(p.duration / dt))
            time = t0 + dt * np.arange(1, N + 1)
        elif len(moving) > 1:
            fxs = [joint_truth[j + 1] for j in moving]
            outm = simulate_multi(actual, moving, fxs, [nominal.drives[j].motor_inertia for j in moving],
                                  [nominal.drives[j].motor_viscous for j in moving], rest, p.ref,
                                  ctrl_robot=nom, t0=t0, dt=dt, t_ref=clock0,
                                  c_nom=[PA10_CV[j + 1][0] for j in moving],
                                  v_nom=[PA10_CV[j + 1][1] for j in moving],
                                  k_nom=[self._k0[j + 1] for j in moving])
            time = outm["time"]
            sig_full = {k: outm[k] for k in ("q", "qd", "qm", "qmd", "u", "f", "tau_t")}
            info["reference"] = [r.to_dict() for r in p.ref]
        else:
            j0 = moving[0]
            fx = joint_truth[j0 + 1]
            dr = nominal.drives[j0]
            I, a, b = actual.single_joint_dynamics(j0, rest)
            In, an, bn = nom.single_joint_dynamics(j0, rest)
            c, v = PA10_CV[j0 + 1]
            plant = JointPlant(I, a, b, dr.motor_inertia, dr.motor_viscous, fx, t_ref=clock0)
            ctrl = Controller.tuned(In, an, bn, dr.motor_inertia, dr.motor_viscous, c, v, self._k0[j0 + 1])
            info["plant"] = {"I": I, "a": a, "b": b, "I_nominal": In, "a_nominal": an,
                             "b_nominal": bn, "kp": ctrl.kp, "kd": ctrl.kd}
            if p.kind == "coastdown":
                r = p.ref
                res, mode, events = simulate_coastdown(plant, ctrl, r["centre"], r["half"], r["vmax"],
                                                       p.vf, t0, dt)
                info["coastdown_releases"] = events
            else:
                Nn = int(round(p.ref.duration / dt))
                q_r, qd_r, qdd_r = p.ref.sample(dt * np.arange(Nn))
                _, qm0, _ = ctrl.feedforward(q_r[:1], qd_r[:1], qdd_r[:1])
                res = simulate_single(plant, ctrl, q_r, qd_r, qdd_r, True,
                                      rest_state(plant, float(qm0[0])), t0, dt)
                info["reference"] = p.ref.to_dict()
            time = res.time
            sig_full = {k: getattr(res, k)[:, None] for k in ("q", "qd", "qm", "qmd", "u", "f", "tau_t")}
            info["newton_max_iter"] = int(res.newton_max_iter)
        refs = [] if not moving else (p.ref if isinstance(p.ref, list) else [p.ref])
        refs = [r if hasattr(r, "sample") else None for r in refs]
        # ---- robot log at the log rate on the controller clock
        t_end = float(time[-1])
        t_log = t0 + np.arange(1, int(math.floor((t_end - t0) * cfg.log_rate + 1e-9)) + 1) / cfg.log_rate
        T = t_log.size

        def at(t, y):
            return np.interp(t, time, y)

        Q = np.tile(rest, (T, 1))
        QD = np.zeros((T, n))
        QDD = np.zeros((T, n))
        QM = Q.copy()
        for k, j in enumerate(moving):
            Q[:, j] = at(t_log, sig_full["q"][:, k])
            QD[:, j] = at(t_log, sig_full["qd"][:, k])
            # mean acceleration over one log interval: what remains of the (overdamped) joint mode
            # (~190 Hz on the PA10 wrist at its declared 5000 N m/rad) averages out
            h = 0.5 / cfg.log_rate
            QDD[:, j] = (at(t_log + h, sig_full["qd"][:, k]) - at(t_log - h, sig_full["qd"][:, k])) / (2 * h)
            QM[:, j] = at(t_log, sig_full["qm"][:, k])
        tau_true = np.atleast_2d(actual.rnea(Q, QD, QDD))      # held joints: holding torque
        for k, j in enumerate(moving):
            tau_true[:, j] = at(t_log, sig_full["u"][:, k])
        res_q = np.array([d.encoder_resolution or math.radians(0.011) for d in nominal.drives])
        qm_meas = np.round(QM / res_q) * res_q
        sig = np.array([cfg.torque_noise if cfg.torque_noise is not None else 0.05 + 0.002 * d.max_torque
                        for d in nominal.drives])
        gain = np.ones(n)
        for j in moving:
            gain[j] = joint_truth[j + 1].torque_gain
        tau_meas = gain * tau_true + rng.normal(0.0, 1.0, size=tau_true.shape) * sig
        extra = {}
        for k, j in enumerate(moving):
            if mode is not None:
                extra[f"mode_{j + 1}"] = at(t_log, mode.astype(float)).round()
            elif refs[k] is not None:
                extra[f"qd_ref_{j + 1}"] = refs[k].sample(t_log - t0)[1]
        _write_log(out / (p.rel + ".csv"), RobotLog(t_log, qm_meas, tau_meas, extra))
        # ---- markers on their own clock (shifted by the time-offset effect)
        toff = max([joint_truth[j + 1].time_offset for j in moving], default=0.0)
        delay = float(rng.uniform(0.05, 0.3))
        early = float(rng.uniform(0.05, 0.3))
        t_m = (t0 + delay) + np.arange(int(math.floor((t_end - early - t0 - delay) * cfg.marker_rate)) + 1) \
            / cfg.marker_rate
        Qm = np.tile(rest, (t_m.size, 1))
        for k, j in enumerate(moving):
            Qm[:, j] = np.interp(t_m - toff, np.concatenate([[t0], time]),
                                 np.concatenate([[sig_full["q"][0, k]], sig_full["q"][:, k]]))
        # a held joint's motor is held, its link gives under the torque it carries at the declared
        # stiffness (FORMAT.md drives.toml ``stiffness``): the encoder reads the motor, the markers see
        # the link (gravity and the coupling from the moving joints)
        if (actual.stiffness > 0).any() and t_m.size:
            QDm, QDDm = np.zeros_like(Qm), np.zeros_like(Qm)
            for j in moving:
                QDm[:, j] = np.interp(t_m - toff, t_log, QD[:, j])
                QDDm[:, j] = np.interp(t_m - toff, t_log, QDD[:, j])
            Qm = Qm + actual.held_deflection(Qm, QDm, QDDm, moving)
            held = [j for j in range(n) if j not in moving]
            arrays[f"{p.id}/marker_q_held"] = Qm[:, held]   # true link angles of the held joints
        # markers are placed by the ACTUAL robot's kinematics (perturbed when asked)
        rec, minfo = synthesize_recording(actual.chain, markers, T_camera_base,
                                          t_m, Qm, rng, errors, rate_hz=cfg.marker_rate)
        write_trc(out / (p.rel + ".trc"), rec, units="mm", overwrite=True, fmt="%.2f")
        info.update({"t_end": t_end, "log_samples": T, "marker_frames": int(t_m.size),
                     "marker_t0": float(t_m[0]), "time_offset_s": toff,
                     "torque_noise_std": sig.tolist(),
                     "occluded_fraction": minfo["occluded_fraction"], "swaps": minfo["swaps"]})
        # ---- truth arrays at the log rate: (T,) for one moving joint, (T, m) for several
        if moving:
            key = p.id
            sq = (lambda a: a[:, 0]) if len(moving) == 1 else (lambda a: a)
            cols = np.array(moving)
            arrays[f"{key}/time"] = t_log
            arrays[f"{key}/q"] = sq(Q[:, cols])
            arrays[f"{key}/qd"] = sq(QD[:, cols])
            arrays[f"{key}/qdd"] = sq(QDD[:, cols])
            arrays[f"{key}/qm"] = sq(QM[:, cols])
            arrays[f"{key}/qmd"] = sq(np.column_stack([at(t_log, y) for y in sig_full["qmd"].T]))
            arrays[f"{key}/f"] = sq(np.column_stack([at(t_log, y) for y in sig_full["f"].T]))
            arrays[f"{key}/u"] = sq(tau_true[:, cols])
            arrays[f"{key}/tau_t"] = sq(np.column_stack([at(t_log, y) for y in sig_full["tau_t"].T]))
            if all(r is not None for r in refs):
                arrays[f"{key}/q_ref"] = sq(np.column_stack([r.sample(t_log - t0)[0] for r in refs]))
            if sink.enabled:
                for k, j in enumerate(moving):
                    base = f"synth/joint{j + 1}"
                    sink.scalars(f"{base}/angle", t_log, np.column_stack([Q[:, j], qm_meas[:, j]]),
                                 names=["q_link_true", "qm_measured"])
                    sink.scalars(f"{base}/torque", t_log,
                                 np.column_stack([tau_true[:, j], tau_meas[:, j],
                                                  at(t_log, sig_full["f"][:, k])]),
                                 names=["u_true", "tau_measured", "friction_true"])
        if sink.enabled:
            sink.points_over_time("world/camera/markers", rec.time, rec.positions, labels=rec.labels)
            Tj = actual.chain.joint_transforms(Qm)
            links = {lk: (Tj[:, jj] @ T_jf if jj >= 0 else np.broadcast_to(T_jf, (t_m.size, 4, 4)))
                     for lk, (jj, T_jf) in actual.chain.frames.items() if lk in self._meshes}
            sink.robot("world/robot", self._meshes, t_m, links)
        return info


def _coast_duration() -> float:
    # 3 speeds x 2 directions x (approach ~2-3 s + ramp + coast 1.5 s + hold 0.5 s): upper bound
    return 40.0


def _write_log(path: Path, log) -> None:
    """FORMAT robot log with per-column precision far below the measurement resolution
    (time 1 us, qm 1e-6 rad vs 1.9e-4 rad encoder, torque 1e-3 N m vs ~0.08 N m noise)."""
    n = log.qm.shape[1]
    names = ["time"] + [f"qm_{j}" for j in range(1, n + 1)] + [f"tau_{j}" for j in range(1, n + 1)] \
        + list(log.extra)
    cols = [np.char.mod("%.6f", log.time)]
    cols += [np.char.mod("%.6f", log.qm[:, j]) for j in range(n)]
    cols += [np.char.mod("%.3f", log.tau[:, j]) for j in range(n)]
    cols += [np.char.mod("%.6g", np.asarray(v, float) + 0.0) for v in log.extra.values()]
    body = np.stack(cols, axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(names) + "\n")
        fh.write("\n".join(",".join(r) for r in body.tolist()))
        fh.write("\n")


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def file_hashes(folder: Path) -> dict:
    """sha256 of every file under ``folder`` (relative path -> hex), for determinism checks."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}
