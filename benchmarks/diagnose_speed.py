"""Speed of ``jointlab diagnose`` on one 60 s, 1 kHz multi-joint record (issue 47 acceptance: at
most 5 s CPU for the 6-joint record, verdicts unchanged), printed as CPU seconds, wall seconds and
as a ratio to a baseline timed in the same run: one plain read of the same campaign's logs
(``Campaign.read_log`` of every trial, what ``jointlab info`` reads; the second of two reads, no
imports in it), so that a slower or a busier machine moves both.

The records: the foreign world's unloaded multi-joint record (``make_world.py --record multi
--effect none``; ``--robot ind6 --seed 1`` and ``--robot tri3 --seed 2``: both logged at 1 kHz)
repeated end to end until 60 s (it starts and ends at rest at the same posture), as the campaign's
only trial (the construction of ``benchmarks/sim2real_speed.py``).

The diagnosis runs in this process (``ident.cli.main.main(["diagnose", ...])``, the command as a
user runs it: reading, diagnosis, ``diagnosis.json``/``.md`` and plots); CPU is
``time.process_time()`` (every thread of this process) plus the CPU of any child process
(``os.times``). The first run pays the imports the log read did not (the diagnosis, matplotlib);
``--repeats N`` runs it N times (the first is the acceptance figure).

    python benchmarks/diagnose_speed.py [--cache DIR] [--robots ind6,tri3] [--repeats N]
        [--profile] [--against TREE] [--breakdown] [--results FILE]

``--profile`` runs the command once more under cProfile and prints (and writes with
``--results``) the top 20 entries by own time and by cumulative time; ``--against TREE`` also
runs this tree and ``TREE`` (another checkout's packages) as child processes of the same run;
``--breakdown`` prints the CPU spent in the main diagnosis functions, per tree, each in a child
process.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, os.environ.get("DIAGNOSE_SPEED_TREE") or str(ROOT))   # --breakdown's children
MAKE = ROOT.parent / "shared" / "worlds" / "foreign" / "make_world.py"
sys.path.append(str(Path(__file__).resolve().parent))   # for _foreign only: benchmarks/ident.py
from _foreign import tile_log  # noqa: E402                 # must not shadow the package

sys.path.remove(str(Path(__file__).resolve().parent))
SEEDS = {"ind6": 1, "tri3": 2}          # the seeds whose records are logged at 1 kHz
ACCEPT_CPU_S = {"ind6": 5.0}            # issue 47: the 6-joint record


def long_campaign(cache: Path, robot: str, seconds: float = 60.0) -> Path:
    """A campaign whose only trial is the foreign world's unloaded record of ``robot`` repeated
    end to end until ``seconds`` (generated once into ``cache``)."""
    seed = SEEDS[robot]
    src = cache / f"{robot}-none-s{seed}"
    if not (src / "campaign.toml").is_file():
        tmp = cache / f"{src.name}.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        cache.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, str(MAKE), str(tmp), "--seed", str(seed), "--record", "multi",
                        "--effect", "none", "--robot", robot], check=True, capture_output=True)
        tmp.rename(src)
    dst = cache / f"{robot}-speed-{int(seconds)}s"
    if (dst / "campaign.toml").is_file():
        return dst
    work = cache / f"{dst.name}.tmp"
    shutil.rmtree(work, ignore_errors=True)
    shutil.copytree(src, work)
    trials = work / "trials"
    logs = sorted(trials.glob("multi-exc-m0-r*.csv"))
    keep = logs[0].stem
    tile_log(logs[0], seconds)
    for p in trials.glob("*.csv"):
        if p.stem != keep:
            p.unlink()
    toml = (work / "campaign.toml").read_text()
    blocks = toml.split("[[trial]]")
    kept = [b for b in blocks[1:] if f'"{keep}"' in b]
    (work / "campaign.toml").write_text(blocks[0] + "".join("[[trial]]" + b for b in kept))
    work.rename(dst)
    return dst


def cpu_now() -> float:
    """CPU seconds of this process (all threads) and of its finished children."""
    ch = os.times()
    return time.process_time() + ch.children_user + ch.children_system


def read_logs(camp: Path) -> tuple:
    """The baseline: one plain read of every log of the campaign (the campaign and its robot
    loaded, then each trial's log read; timed on the second of two reads, so that neither pays
    the imports) -> (cpu s, wall s, seconds of record, rate Hz, joints)."""
    from mocap.io.campaign import load_campaign

    for _ in range(2):
        c0, w0 = cpu_now(), time.perf_counter()
        c = load_campaign(camp)
        robot = c.load_robot()
        logs = [c.read_log(tr, robot) for tr in c.trials]
        cpu, wall = cpu_now() - c0, time.perf_counter() - w0
    t = np.asarray(logs[0].time, float)
    return cpu, wall, sum(float(lg.time[-1] - lg.time[0]) for lg in logs), 1.0 / float(np.median(np.diff(t))), robot.n


def diagnose(camp: Path, out: Path) -> tuple:
    """``jointlab diagnose CAMP --out OUT`` in this process -> (cpu s, wall s, verdicts)."""
    from ident.cli.main import main as jl

    shutil.rmtree(out, ignore_errors=True)
    c0, w0 = cpu_now(), time.perf_counter()
    rc = jl(["diagnose", str(camp), "--out", str(out)])
    cpu, wall = cpu_now() - c0, time.perf_counter() - w0
    if rc != 0:
        raise SystemExit(f"jointlab diagnose {camp} exited {rc}")
    rep = json.loads((out / "diagnosis.json").read_text())
    verdicts = {j: r["verdict"] for j, r in sorted(rep["joints"].items(), key=lambda kv: int(kv[0]))}
    return cpu, wall, verdicts


def diagnose_other(tree: Path, camp: Path, out: Path) -> tuple:
    """The same command with the packages of another source tree ``tree`` (e.g. the commit before
    a change, ``git archive COMMIT | tar -x -C TREE``), in a child process of this run -> (cpu s
    of the child, wall s, verdicts). The child pays its interpreter start and every import."""
    shutil.rmtree(out, ignore_errors=True)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    code = "import sys; from ident.cli.main import main; sys.exit(main(sys.argv[1:]))"
    c0, w0 = cpu_now(), time.perf_counter()
    rc = subprocess.run([sys.executable, "-c", code, "diagnose", str(camp), "--out", str(out)], env=env,
                        cwd=tempfile.gettempdir(), capture_output=True, text=True)
    cpu, wall = cpu_now() - c0, time.perf_counter() - w0
    if rc.returncode != 0:
        raise SystemExit(f"{tree}: jointlab diagnose exited {rc.returncode}: {rc.stderr[-500:]}")
    rep = json.loads((out / "diagnosis.json").read_text())
    return cpu, wall, {j: r["verdict"] for j, r in sorted(rep["joints"].items(), key=lambda kv: int(kv[0]))}


#: the functions --breakdown times (module, attribute path, modules that imported it by name)
BREAKDOWN = (("ident.gap.diagnose", "diagnose_joint", ("ident.model.multijoint",)),
             ("ident.gap.channels", "Channel.prep_effect", ()),
             ("ident.gap.engine", "cross_validate", ("ident.gap.diagnose", "ident.gap.channels")),
             ("ident.gap.engine", "grams_augmented", ("ident.gap.diagnose",)),
             ("ident.gap.report", "make_plots", ()),
             ("ident.model.multijoint", "identified_rigid_body", ()),
             ("ident.gap.data", "build_joint_data_record", ("ident.model.multijoint",)),
             ("ident.gap.data", "_record_signal_columns", ()),
             ("ident.gap.diagnose", "_columns", ()))


def breakdown_child(camp: Path, out: Path) -> None:
    """(In a child process) the command with the CPU of each :data:`BREAKDOWN` function summed
    over its calls, printed as ``name seconds`` lines (nested entries overlap)."""
    import functools
    import importlib

    acc = {}

    def wrap(modname, path, users):
        obj = importlib.import_module(modname)
        *owner, attr = path.split(".")
        for part in owner:
            obj = getattr(obj, part)
        if not hasattr(obj, attr):
            return
        f = getattr(obj, attr)

        @functools.wraps(f)
        def timed(*a, **k):
            c0 = time.process_time()
            try:
                return f(*a, **k)
            finally:
                acc[path] = acc.get(path, 0.0) + time.process_time() - c0
        setattr(obj, attr, timed)
        for u in users:   # modules that bound the name at import
            m = importlib.import_module(u)
            if getattr(m, attr, None) is f:
                setattr(m, attr, timed)

    from ident.cli.main import main as jl

    for modname, path, users in BREAKDOWN:
        wrap(modname, path, users)
    c0 = time.process_time()
    jl(["diagnose", str(camp), "--out", str(out)])
    print(f"the command {time.process_time() - c0:.2f}")
    for _, path, _ in BREAKDOWN:
        print(f"{path} {acc.get(path, float('nan')):.2f}")


def breakdown(trees: list, camp: Path, tmp: Path) -> list:
    """:func:`breakdown_child` of each (label, tree) in a child process -> table lines."""
    cols = []
    for label, tree in trees:
        shutil.rmtree(tmp / "breakdown", ignore_errors=True)
        env = {**os.environ, "DIAGNOSE_SPEED_TREE": str(tree), "PYTHONPATH": str(tree)}
        rc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--breakdown-child", str(camp),
                             str(tmp / "breakdown")], env=env, cwd=tempfile.gettempdir(), capture_output=True,
                            text=True)
        rows = dict(ln.rsplit(" ", 1) for ln in rc.stdout.splitlines() if ln and not ln.startswith(("joint", "wrote")))
        cols.append((label, rows))
    names = list(cols[0][1])
    out = ["  CPU s per function (summed over calls; nested entries overlap): " + " | ".join(lb for lb, _ in cols)]
    out += [f"    {n}: " + " | ".join(c.get(n, "-") for _, c in cols) for n in names]
    return out


def profile(camp: Path, out: Path, top: int = 20) -> str:
    """The command once under cProfile: the top entries by own time and by cumulative time."""
    from ident.cli.main import main as jl

    shutil.rmtree(out, ignore_errors=True)
    pr = cProfile.Profile()
    pr.enable()
    jl(["diagnose", str(camp), "--out", str(out)])
    pr.disable()
    text = []
    for key in ("tottime", "cumulative"):
        s = io.StringIO()
        pstats.Stats(pr, stream=s).strip_dirs().sort_stats(key).print_stats(top)
        body = s.getvalue()
        body = body[body.index("   ncalls"):] if "   ncalls" in body else body
        total = pstats.Stats(pr).total_tt
        text.append(f"cProfile top {top} by {key} (profiled total {total:.2f} s):\n{body.rstrip()}")
    return "\n\n".join(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "jointlab-diagnose-speed")
    ap.add_argument("--robots", default="ind6,tri3")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="also time the command with the packages of this source tree (child process)")
    ap.add_argument("--breakdown", action="store_true",
                    help="CPU per diagnosis function, this tree (and --against), each in a child process")
    ap.add_argument("--breakdown-child", nargs=2, type=Path, metavar=("CAMPAIGN", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--results", type=Path, help="also write what is printed to this file")
    a = ap.parse_args(argv)
    if a.breakdown_child:
        breakdown_child(*a.breakdown_child)
        return 0
    lines = [f"# python benchmarks/diagnose_speed.py {' '.join(argv if argv is not None else sys.argv[1:])}",
             f"# OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
             f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start"]

    def say(s=""):
        print(s, flush=True)
        lines.append(s)

    for ln in lines:
        print(ln)
    tmp = Path(tempfile.mkdtemp(prefix="diagnose-speed-"))
    first = True
    try:
        for robot in a.robots.split(","):
            camp = long_campaign(a.cache, robot)
            b_cpu, b_wall, dur, rate, n = read_logs(camp)
            say(f"{robot}: one record of {dur:.1f} s at {rate:.0f} Hz, {n} joints ({camp})")
            say(f"  baseline, one plain read of the campaign's logs: {b_cpu:.2f} s CPU, {b_wall:.2f} s wall")
            for r in range(a.repeats):
                cpu, wall, verdicts = diagnose(camp, tmp / f"{robot}-{r}")
                acc = ACCEPT_CPU_S.get(robot)
                note = "" if acc is None or r else \
                    f"; acceptance (<= {acc:g} s CPU per 60 s record): {'met' if cpu * 60 / dur <= acc else 'NOT met'}"
                say(f"  jointlab diagnose, run {r + 1}{' (with its imports)' if first else ''}: "
                    f"{cpu:.2f} s CPU = {cpu / b_cpu:.1f} log reads, {wall:.2f} s wall{note}")
                first = False
            say(f"  verdicts: {', '.join(f'j{j} {v}' for j, v in verdicts.items())}")
            if a.against is not None:   # both trees as child processes (start and imports included)
                for label, tree in (("this tree", ROOT), (str(a.against), a.against)):
                    o_cpu, o_wall, o_verdicts = diagnose_other(tree, camp, tmp / f"{robot}-child")
                    say(f"  child process with {label}: {o_cpu:.2f} s CPU = {o_cpu / b_cpu:.1f} log reads, "
                        f"{o_wall:.2f} s wall; verdicts {'the same' if o_verdicts == verdicts else o_verdicts}")
            if a.breakdown:
                for ln in breakdown([("this tree", ROOT)] + ([(str(a.against), a.against)] if a.against else []),
                                    camp, tmp):
                    say(ln)
            if a.profile:
                say(profile(camp, tmp / f"{robot}-profile"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if a.results:
        a.results.parent.mkdir(parents=True, exist_ok=True)
        a.results.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
