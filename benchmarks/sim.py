"""Simulator speed: simulated seconds per wall second for a default trial (joint 5 of the bundled
PA10, 20 s finite-Fourier excitation at full speed, 2 kHz), per effect, against a baseline
measured in the same run: the several-joint mode (pinocchio + numpy per step) on the same
joint. Then the default campaign (``jointlab synth``: 2 loads x 3 speeds x 5 repetitions).

    python benchmarks/sim.py            # full
    python benchmarks/sim.py --quick    # short trial, no campaign

Goal: > 20x real time on one core for the single-joint mode; default campaign < 60 s.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ident.sim.effects import K_NOMINAL, Effect  # noqa: E402
from ident.excitation.trajectories import fourier_excitation  # noqa: E402
from ident.sim.plant import Controller, JointPlant, simulate_multi, simulate_reference  # noqa: E402
from ident.sim.campaign_synth import PA10_CV, REST_POSE, PA10_DIR  # noqa: E402
from mocap.robot import Robot  # noqa: E402


def best_of(fn, n):
    best = np.inf
    for _ in range(n):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 s trial, 1 repeat, no campaign")
    args = ap.parse_args()
    duration = 5.0 if args.quick else 20.0
    reps = 1 if args.quick else 3
    robot = Robot.from_urdf(PA10_DIR / "pa10.urdf", PA10_DIR / "drives.toml")
    j0 = 4
    dr = robot.drives[j0]
    c, v = PA10_CV[5]
    I, a, b = robot.single_joint_dynamics(j0, np.array(REST_POSE))
    ref = fourier_excitation(np.random.default_rng(0), dr.max_velocity, 1.0, duration, 0.6, 1.2)
    ctrl = Controller.tuned(I, a, b, dr.motor_inertia, dr.motor_viscous, c, v, K_NOMINAL)
    print(f"trial: joint 5, {ref.duration:.1f} s simulated at 2 kHz, best of {reps}")
    rows = []
    for name in ("none", "stribeck", "presliding", "backlash", "load_dependent"):
        fx = Effect(name, 1.0).joint_params(c, v, dr.max_torque, dr.max_velocity, I + dr.motor_inertia)
        plant = JointPlant(I, a, b, dr.motor_inertia, dr.motor_viscous, fx)
        wall = best_of(lambda: simulate_reference(plant, ctrl, ref, 0.0), reps)
        rows.append((name, wall))
    # baseline: several-joint mode on the same single joint (pinocchio + numpy per step)
    fx = Effect("none").joint_params(c, v, dr.max_torque, dr.max_velocity, I + dr.motor_inertia)
    base_dur = min(ref.duration, 4.0)
    ref_b = fourier_excitation(np.random.default_rng(0), dr.max_velocity, 1.0, base_dur, 0.6, 1.2)
    wall_b = best_of(lambda: simulate_multi(robot, [j0], [fx], [dr.motor_inertia], [dr.motor_viscous],
                                            REST_POSE, [ref_b]), 1)
    rt_b = ref_b.duration / wall_b
    print(f"{'mode / effect':<28}{'wall s':>9}{'x real time':>13}{'vs baseline':>13}")
    print(f"{'multi-joint (baseline)':<28}{wall_b:>9.3f}{rt_b:>13.1f}{1.0:>13.1f}")
    for name, wall in rows:
        rt = ref.duration / wall
        print(f"{'single-joint ' + name:<28}{wall:>9.3f}{rt:>13.1f}{rt / rt_b:>13.1f}")
    ok = ref.duration / rows[0][1] > 20
    print(f"goal > 20x real time (single joint, nominal): {'met' if ok else 'NOT met'}")
    if not args.quick:
        from ident.cli.main import main as cli

        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            rc = cli(["synth", str(Path(tmp) / "camp"), "--quiet"])
            wall = time.perf_counter() - t
            size = sum(p.stat().st_size for p in (Path(tmp) / "camp").rglob("*") if p.is_file())
        print(f"default campaign (30 trials x 20 s + static + 2 sweeps): {wall:.1f} s wall, "
              f"{size / 1e6:.1f} MB, rc={rc}; goal < 60 s: {'met' if wall < 60 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
