"""Benchmark: ``jointlab info`` on a long robot log (issue 30).

Goal: a 10-million-row, 13-column log (``time``, ``qm_1..6``, ``tau_1..6``: a 6-joint controller
log at 5 kHz for 33 minutes) in at most 15 s and 1.5 GB peak resident. Each command runs in its
own process under ``/usr/bin/time``, which reports its wall time and peak resident set.

Beside ``jointlab info`` on the long log, the same invocation times two baselines on a shorter
log of the same kind (``--base-rows``, default 1 M rows; the old reader needs about 0.7 KB per
row, too much for a shared machine at 10 M rows): the careful line-by-line parser (the reader
every log went through before the streaming reader, ``mocap.io.robotlog._read_careful``) and a
plain ``numpy.loadtxt`` of the table, and ``jointlab info`` on that shorter log, so that the
ratios compare like with like.

    python benchmarks/longlog.py                       # 10 M rows (generated once, cached)
    python benchmarks/longlog.py --rows 2000000        # a smaller log
    python benchmarks/longlog.py --no-baseline         # only the long-log run
    python benchmarks/longlog.py --record --only fit   # fit --models cv, 1 h at 1 kHz, 7 joints
    python benchmarks/longlog.py --record --only diagnose --duration 300   # diagnose, 5 min

``--record``: goal (issue 30) ``jointlab fit --models cv`` and ``jointlab diagnose`` on a 1-hour,
1 kHz, 7-joint log each in at most 60 s and 2 GB; the record is decimated by the shared record
layer (``ident.model.record``, docs/long-records.md) and the decimation line of ``rigidbody.md``
is printed. The 7-joint campaign (``fixtures/arm7``) is made by :func:`make_arm7_campaign`.

The logs are made here with their own generator (sines and noise, written by pyarrow's CSV
writer, cells rounded to 1e-6 rad and 1e-4 N m) into a cache folder and reused.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GOAL_S = 15.0
GOAL_GB = 1.5
GOAL_REC_S = 60.0
GOAL_REC_GB = 2.0
RATE_HZ = 5000.0
N_JOINTS = 6


def make_log(rows: int, cache: Path, seed: int = 3) -> Path:
    """A ``rows``-row log at :data:`RATE_HZ`: per joint a sum of two sines plus noise for the
    angle, a noisy torque; written in blocks of 1 M rows."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    path = cache / f"longlog-{rows}.csv"
    if path.is_file():
        return path
    print(f"writing a {rows}-row log to {path} (once) ...", flush=True)
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    names = ["time"] + [f"qm_{j + 1}" for j in range(N_JOINTS)] + [f"tau_{j + 1}" for j in range(N_JOINTS)]
    f = rng.uniform(0.05, 0.5, size=(2, N_JOINTS))
    tmp = path.with_suffix(".part")
    tmp.write_text(",".join(names) + "\n")
    with open(tmp, "ab") as fh, pacsv.CSVWriter(
            fh, pa.schema([(n, pa.float64()) for n in names]),
            write_options=pacsv.WriteOptions(include_header=False, quoting_style="none")) as w:
        for a in range(0, rows, 1_000_000):
            i = np.arange(a, min(rows, a + 1_000_000))
            t = i / RATE_HZ
            ph = 2 * np.pi * t[:, None]
            q = np.sin(ph * f[0]) + 0.3 * np.sin(ph * f[1]) + 1e-5 * rng.standard_normal((i.size, N_JOINTS))
            tau = 5 * np.cos(ph * f[0]) + 0.2 * rng.standard_normal((i.size, N_JOINTS))
            cols = [np.round(t, 6)] + list(np.round(q, 6).T) + list(np.round(tau, 4).T)
            w.write_batch(pa.record_batch([pa.array(c) for c in cols], names=names))
    tmp.rename(path)
    print(f"  {path.stat().st_size / 1e9:.2f} GB in {time.perf_counter() - t0:.0f} s", flush=True)
    return path


ARM7 = REPO / "fixtures" / "arm7" / "arm7.urdf"


def make_arm7_campaign(duration: float, rate: float, cache: Path, seed: int = 5) -> Path:
    """A campaign of the 7-joint ``fixtures/arm7`` arm with one multi-joint trial of
    ``duration`` s logged at ``rate`` Hz: every joint a sum of three sines whose frequencies
    (0.35-0.9 Hz) are multiples of 1/60 Hz, so that the motion repeats every minute and
    pinocchio's ``rnea`` runs over one minute only; Coulomb + viscous friction and an offset per
    joint, torque noise, encoder quantisation of 2e-5 rad. Written in blocks of one minute."""
    import numpy as np
    import pinocchio as pin
    import pyarrow as pa
    import pyarrow.csv as pacsv

    root = cache / f"arm7-{duration:g}s-{rate:g}hz"
    if (root / "campaign.toml").is_file():
        return root
    print(f"writing a {duration:g} s, {rate:g} Hz 7-joint campaign to {root} (once) ...", flush=True)
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    model = pin.buildModelFromUrdf(str(ARM7))
    data = model.createData()
    n = model.nq
    period = 60.0
    w = 2 * np.pi * rng.integers(21, 55, (n, 3)) / period
    a = rng.uniform(0.15, 0.35, (n, 3)) / np.array([1.0, 1.6, 2.4])
    ph = rng.uniform(0, 2 * np.pi, (n, 3))
    tp = np.arange(int(round(period * rate))) / rate
    arg = tp[:, None, None] * w[None] + ph[None]
    q = np.sum(a * np.sin(arg), axis=2)
    qd = np.sum(a * w * np.cos(arg), axis=2)
    qdd = -np.sum(a * w ** 2 * np.sin(arg), axis=2)
    rigid = np.array([pin.rnea(model, data, q[k], qd[k], qdd[k]) for k in range(tp.size)])
    fc = np.array([3.0, 4.0, 2.0, 2.5, 0.8, 0.6, 0.3])
    fv = np.array([6.0, 5.0, 3.0, 3.0, 1.0, 0.8, 0.4])
    off = np.array([0.3, -0.5, 0.2, 0.1, -0.05, 0.04, 0.02])
    tau_p = rigid + fc * np.sign(qd) + fv * qd + off
    qm_p = np.round(q / 2e-5) * 2e-5
    (root / "robot").mkdir(parents=True, exist_ok=True)
    (root / "trials").mkdir(exist_ok=True)
    (root / "robot" / "arm7.urdf").write_bytes(ARM7.read_bytes())
    (root / "robot" / "drives.toml").write_text("".join(
        f'[[joint]]\nname = "a{j}"\ngear_ratio = 100.0\n\n' for j in range(1, n + 1)), encoding="utf-8")
    names = ["time"] + [f"qm_{j}" for j in range(1, n + 1)] + [f"tau_{j}" for j in range(1, n + 1)]
    log = root / "trials" / "rec.csv"
    log.write_text(",".join(names) + "\n")
    n_total = int(round(duration * rate))
    with open(log, "ab") as fh, pacsv.CSVWriter(
            fh, pa.schema([(c, pa.float64()) for c in names]),
            write_options=pacsv.WriteOptions(include_header=False, quoting_style="none")) as wr:
        for a0 in range(0, n_total, tp.size):
            m = min(tp.size, n_total - a0)
            t = np.round((a0 + np.arange(m)) / rate, 6)
            tau = np.round(tau_p[:m] + 0.1 * rng.standard_normal((m, n)), 4)
            cols = [t] + list(np.round(qm_p[:m], 5).T) + list(tau.T)
            wr.write_batch(pa.record_batch([pa.array(c) for c in cols], names=names))
    (root / "campaign.toml").write_text(
        'format = 1\nname = "arm7-long"\n\n[robot]\nurdf = "robot/arm7.urdf"\n'
        'drives = "robot/drives.toml"\n\n[[trial]]\nid = "rec"\njoints = [1, 2, 3, 4, 5, 6, 7]\n'
        'kind = "excitation"\nlog = "trials/rec.csv"\n', encoding="utf-8")
    print(f"  {log.stat().st_size / 1e9:.2f} GB in {time.perf_counter() - t0:.0f} s", flush=True)
    return root


def timed(code: str | list, label: str) -> tuple[float, float, float]:
    """Wall seconds, peak resident GB and CPU seconds (user + system) of one child process
    (``/usr/bin/time``); on a shared machine the CPU time is the steadier figure."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as tf:
        argv = [sys.executable, "-c", code] if isinstance(code, str) else [sys.executable, *code]
        env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
        r = subprocess.run(["/usr/bin/time", "-o", tf.name, "-f", "%e %M %U %S", *argv], env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if r.returncode != 0:
            raise SystemExit(f"{label} failed ({r.returncode}):\n{r.stderr[-2000:]}")
        wall, kb, user, system = tf.read().split()[-4:]
    return float(wall), float(kb) * 1024 / 1e9, float(user) + float(system)


def long_record(a) -> int:
    """``jointlab fit --models cv`` and ``jointlab diagnose`` on the long 7-joint record."""
    camp = make_arm7_campaign(a.duration, a.rate, a.cache)
    rows = int(round(a.duration * a.rate))
    print(f"record: {a.duration:g} s at {a.rate:g} Hz, 7 joints ({rows} rows); load {os.getloadavg()[0]:.1f}",
          flush=True)
    out = Path(tempfile.mkdtemp(prefix="jl-longrec-"))
    res = {}
    for name, argv in (("fit --models cv", ["fit", str(camp), "--models", "cv", "--out", str(out / "fit")]),
                       ("diagnose", ["diagnose", str(camp), "--out", str(out / "diag")])):
        if a.only and not name.startswith(a.only):
            continue
        wall, gb, cpu = timed(["-m", "ident.cli", *argv], f"jointlab {name}")
        ok = wall <= GOAL_REC_S and gb <= GOAL_REC_GB
        print(f"jointlab {name}: {wall:.1f} s ({cpu:.1f} s CPU), peak {gb:.2f} GB resident "
              f"(goal <= {GOAL_REC_S:.0f} s, <= {GOAL_REC_GB:g} GB: {'met' if ok else 'NOT met'})", flush=True)
        res[name] = {"wall_s": wall, "cpu_s": cpu, "peak_gb": gb}
    if (out / "fit" / "rigidbody.md").is_file():
        print("decimation:", _decimation_text(out))
    print(json.dumps({"rows": rows, **res}))
    return 0


def _decimation_text(out: Path) -> str:
    md = (out / "fit" / "rigidbody.md").read_text().splitlines()
    return next((ln[2:] for ln in md if ln.startswith("- decimated")), "none")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=10_000_000)
    ap.add_argument("--base-rows", type=int, default=1_000_000)
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--record", action="store_true",
                    help="instead: fit --models cv and diagnose on a long 7-joint record")
    ap.add_argument("--duration", type=float, default=3600.0, help="--record: seconds")
    ap.add_argument("--rate", type=float, default=1000.0, help="--record: log rate, Hz")
    ap.add_argument("--only", choices=("fit", "diagnose"), default=None, help="--record: one command")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "jointlab-bench")
    a = ap.parse_args(argv)
    a.cache.mkdir(parents=True, exist_ok=True)
    if a.record:
        return long_record(a)
    big = make_log(a.rows, a.cache)
    size = big.stat().st_size
    cmd = ["-m", "ident.cli", "info", str(big)]
    print(f"log: {a.rows} rows x {1 + 2 * N_JOINTS} columns, {size / 1e9:.2f} GB; load {os.getloadavg()[0]:.1f}",
          flush=True)
    wall, gb, cpu = timed(cmd, "jointlab info")
    print(f"jointlab info ({a.rows} rows): {wall:.1f} s ({cpu:.1f} s CPU), peak {gb:.2f} GB resident "
          f"(goal <= {GOAL_S:.0f} s, <= {GOAL_GB} GB: {'met' if wall <= GOAL_S and gb <= GOAL_GB else 'NOT met'})",
          flush=True)
    if not a.no_baseline:
        small = make_log(a.base_rows, a.cache)
        n = a.base_rows
        w_new, g_new, c_new = timed(["-m", "ident.cli", "info", str(small)], "jointlab info (short)")
        careful = ("from pathlib import Path; from mocap.io.robotlog import _read_careful; "
                   f"log = _read_careful(Path({str(small)!r}), None); log.sampling()")
        w_old, g_old, c_old = timed(careful, "careful reader")
        loadtxt = ("import numpy as np; "
                   f"a = np.loadtxt({str(small)!r}, delimiter=',', skiprows=1, ndmin=2)")
        w_np, g_np, c_np = timed(loadtxt, "numpy.loadtxt")
        print(f"baselines on {n} rows (same invocation):")
        print(f"  jointlab info          {w_new:6.2f} s  {c_new:6.2f} s CPU  {g_new:5.2f} GB")
        print(f"  careful reader (old)   {w_old:6.2f} s  {c_old:6.2f} s CPU  {g_old:5.2f} GB   "
              f"info: {w_old / w_new:.1f}x faster ({c_old / c_new:.1f}x less CPU), "
              f"{g_old / g_new:.1f}x less memory")
        print(f"  numpy.loadtxt          {w_np:6.2f} s  {c_np:6.2f} s CPU  {g_np:5.2f} GB   "
              f"info: {w_np / w_new:.1f}x faster ({c_np / c_new:.1f}x less CPU), "
              f"{g_np / g_new:.1f}x less memory")
        print(f"  old reader extrapolated to {a.rows} rows: ~{w_old * a.rows / n:.0f} s, "
              f"~{g_old * a.rows / n:.1f} GB (linear in rows)")
    print(json.dumps({"rows": a.rows, "wall_s": wall, "cpu_s": cpu, "peak_gb": gb}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
