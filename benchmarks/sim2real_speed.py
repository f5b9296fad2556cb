"""Speed of ``jointlab sim2real`` on a 60 s, 6-joint record at 1 kHz (issue 43 acceptance: the whole
command within 60 s on 2 cores), printed as seconds and as a ratio to one plain MuJoCo rollout of
the whole record (``mujoco.rollout``, the given model, logged torque) timed in the same run: the
command as it comes (it runs the gap diagnosis and writes its ``diagnosis.json``), then the same
command again reusing that diagnosis (``--diagnosis OUT/diagnosis.json``).

The record: the foreign world's unloaded multi-joint record (``make_world.py --record multi
--robot ind6 --seed 1``: 1 kHz) repeated end to end until 60 s (it starts and ends at rest at the
same posture), as the campaign's only trial.

    python benchmarks/sim2real_speed.py [--cache DIR] [--threads 2] [--no-sysid]
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MAKE = ROOT.parent / "shared" / "worlds" / "foreign" / "make_world.py"
sys.path.append(str(Path(__file__).resolve().parent))   # for _foreign only: benchmarks/ident.py
from _foreign import tile_log  # noqa: E402                 # must not shadow the package

sys.path.remove(str(Path(__file__).resolve().parent))


def long_campaign(cache: Path, seconds: float = 60.0) -> Path:
    src = cache / "none-s1"
    if not (src / "campaign.toml").is_file():
        subprocess.run([sys.executable, str(MAKE), str(src), "--seed", "1", "--record", "multi",
                        "--effect", "none", "--robot", "ind6"], check=True, capture_output=True)
    dst = cache / f"speed-{int(seconds)}s"
    if (dst / "campaign.toml").is_file():
        return dst
    shutil.copytree(src, dst)
    trials = dst / "trials"
    log = trials / "multi-exc-m0-r2.csv"
    tile_log(log, seconds)
    (trials / "multi-exc-m3-r1.csv").unlink()
    toml = (dst / "campaign.toml").read_text()
    blocks = toml.split("[[trial]]")
    keep = [b for b in blocks[1:] if "multi-exc-m3-r1" not in b]
    (dst / "campaign.toml").write_text(blocks[0] + "".join("[[trial]]" + b for b in keep))
    return dst


def plain_rollout_seconds(camp: Path) -> tuple:
    """Seconds of one plain rollout of the whole record (given model, logged torque), and its length."""
    from mocap.io.campaign import load_campaign
    from ident.sim2real.model import build_model
    from ident.sim2real.replay import Replayer, records_of

    c = load_campaign(camp)
    robot = c.load_robot()
    sm = build_model(c, robot)
    rec = records_of(c, robot)[0]
    rp = Replayer(sm, robot, rec)
    L = rec.t.size - 1
    t0 = time.perf_counter()
    rp.simulate(sm.given, np.array([0]), L)
    return time.perf_counter() - t0, rec.t[-1] - rec.t[0], rec.dt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, default=Path("/tmp/s2r-corpus"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-sysid", action="store_true")
    a = ap.parse_args(argv)
    import json
    import tempfile
    from ident.cli.main import main as jl

    camp = long_campaign(a.cache)
    base, dur, dt = plain_rollout_seconds(camp)
    tmp = Path(tempfile.mkdtemp())
    print(f"record {dur:.1f} s at {1 / dt:.0f} Hz, 6 joints; threads {a.threads}; "
          f"sysid {'off' if a.no_sysid else 'on'}")
    print(f"one plain rollout of the record: {base:.2f} s")
    common = ["--threads", str(a.threads)] + (["--no-sysid"] if a.no_sysid else [])
    runs = [("whole command", tmp / "out", []),
            ("whole command reusing its diagnosis (--diagnosis)", tmp / "out2",
             ["--diagnosis", str(tmp / "out" / "diagnosis.json")])]
    for label, out, extra in runs:
        t0 = time.perf_counter()
        rc = jl(["sim2real", str(camp), "--out", str(out)] + common + extra)
        total = time.perf_counter() - t0
        rep = json.loads((out / "sim2real.json").read_text())
        st = ", ".join(f"{k} {v:.1f}" for k, v in rep["seconds"].items())
        print(f"{label} (rc {rc}): {total:.1f} s = {total / base:.0f} plain rollouts; stages: {st}; "
              f"acceptance (<= 60 s): {'met' if total <= 60 else 'NOT met'}", flush=True)
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
