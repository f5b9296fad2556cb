"""Benchmark: a whole study (calibration, link angles, friction fits, diagnosis, report, .rrd).

Goals (issue 9): a full PA10-style campaign (6 joints x 2 loads x 3 speed ranges x 5
repetitions, 20 s trials, 200 Hz) end to end in under 3 minutes on 2 cores with a peak memory
under 4 GB; near-linear speed-up from 1 to 2 local workers; the same code path on Dask.
Issue 13: the same 180-trial study in at most 90 s on 2 workers with no accuracy lost. Beside
the wall times, the CPU (process) time the workers spent per trial in each mapped stage is
printed: other load on a shared machine stretches wall times, much less CPU times.

    python benchmarks/study.py            # the full campaign (synthesised once, cached)
    python benchmarks/study.py --quick    # 2 joints x 1 load x 3 speeds x 2 reps, 8 s trials
    python benchmarks/study.py --workers 2 --no-resume   # only the 2-worker run
    python benchmarks/study.py --memory --trials 180 --duration 20 [--diagnosis-reps 5]

Issue 30: the 180-trial study in at most 35 s on 2 workers; ``--memory``: an N-trial and a
10 N-trial study (more repetitions), each in a fresh child process, peak memory ratio <= 1.2
(trial length ``--duration``; ``--diagnosis-reps`` bounds the per-joint diagnosis further, which
holds a joint's kept samples while it runs: docs/study-memory.md).

Issue 47: the 180-trial study in at most 35 s on 2 workers. The baseline is the ``jointlab
info`` pass over the same campaign (it reads every marker file and log once), timed in this
process just before and just after the 2-worker study: the study's wall and CPU times are
printed as ratios to it. ``--against TREE`` also runs the 2-worker study with another checkout
of jointlab (e.g. ``git worktree add /tmp/head HEAD``) in a child process of this invocation,
between the same info passes, and prints the wall ratio; ``--results FILE`` writes what is
printed to a file.

    python benchmarks/study.py --workers 2 --no-resume --against /tmp/head \
        --results benchmarks/results/study.txt

The campaign is made by ``jointlab synth`` (18 markers: 3 per link, the synthesiser's minimum
for a rigid-body pose per link; the goal names 16) into a cache folder and reused. Each run goes
into a fresh output folder; peak memory is the largest sum of the resident set sizes of this
process and its worker processes, sampled every 0.1 s. The baseline is the 1-worker (serial)
run of the same campaign in the same invocation; ratios are printed against it.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ident.cli.main import main as cli  # noqa: E402
from ident.study.executor import make_executor  # noqa: E402
from ident.study.study import DIAGNOSIS_SAMPLES, Study, StudySettings  # noqa: E402

FULL = dict(joints="1,2,3,4,5,6", loads="0,3.373", vmax="0.3,0.6,1.0", reps=5, duration=20.0, rate=200.0)
QUICK = dict(joints="2,5", loads="0", vmax="0.3,0.6,1.0", reps=2, duration=8.0, rate=200.0)
GOAL_S = 180.0
GOAL13_S = 90.0
GOAL_GB = 4.0
GOAL_MEM_RATIO = 1.2          # issue 30: a 10x study within 1.2x the peak memory of a 1x one
GOAL47_S = 35.0               # issue 47: the 180-trial study on 2 workers (it was 44-46 s = 7x info)
ISSUE47_INFO_RATIO = 7.0 * GOAL47_S / 45.0    # that goal as a ratio to the info pass (~5.4)


class Tee:
    """print() to stdout and, with ``path``, to a results file written at the end."""

    def __init__(self, path: Path | None = None):
        self.path, self.lines = path, []

    def __call__(self, *parts, **kw):
        text = " ".join(str(p) for p in parts)
        print(text, flush=True)
        self.lines.append(text)

    def close(self):
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text("\n".join(self.lines) + "\n")
            print(f"wrote {self.path}", flush=True)


def info_pass(camp: Path) -> dict:
    """The baseline: ``jointlab info CAMPAIGN`` (reads every marker file and log of the campaign
    once and describes them) in this process, its output discarded; wall and CPU seconds."""
    import contextlib
    import io

    t0, c0 = time.perf_counter(), time.process_time()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli(["info", str(camp)])
    if rc != 0:
        raise SystemExit(f"jointlab info failed ({rc})")
    return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}


#: the child of ``--against``: one study with the checkout on sys.path first; JSON on stdout
_AGAINST = """
import json, os, sys, time
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from ident.study.executor import make_executor
from ident.study.study import Study, StudySettings
ex = make_executor(int(sys.argv[4]), progress=False)
t0, c0 = time.perf_counter(), time.process_time()
try:
    r = Study(StudySettings(), ex, progress=False).run(Path(sys.argv[2]), Path(sys.argv[3]))
finally:
    ex.close()
wall, main_cpu = time.perf_counter() - t0, time.process_time() - c0
import ident
print(json.dumps({"wall": wall, "main_cpu": main_cpu, "errors": r.errors, "stages": r.to_dict()["stages"],
                  "where": ident.__file__}))
"""


def run_against(tree: Path, camp: Path, out: Path, workers: int) -> dict:
    """The study of ``camp`` with the jointlab checkout ``tree`` (a before-figure), in a child
    process; its wall time and the stage rows, and that the child imported that tree."""
    import json
    import subprocess

    shutil.rmtree(out, ignore_errors=True)
    r = subprocess.run([sys.executable, "-c", _AGAINST, str(tree), str(camp), str(out), str(workers)],
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(tree)})
    if r.returncode != 0:
        raise SystemExit(f"the study with {tree} failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    if not Path(res["where"]).resolve().is_relative_to(Path(tree).resolve()):
        raise SystemExit(f"--against {tree}: the child imported {res['where']}")
    return res


class PeakRSS:
    """Largest summed RSS of this process and its descendants, sampled in a thread."""

    def __init__(self, period: float = 0.1, pid: int | None = None, pss: bool = False):
        try:
            import psutil
        except ImportError:
            raise SystemExit("benchmarks/study.py needs psutil: pip install -e \".[bench]\"") from None

        self._p = psutil.Process(pid)
        self._psutil = psutil
        self.period = period
        self.peak = 0
        self.pss = pss              # also sum the proportional set sizes (reads smaps: slower)
        self.peak_pss = 0           # the same sum of proportional set sizes (shared pages split)
        self.by_role: dict = {}     # "main" / "worker" -> largest RSS of one such process
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> tuple[int, int]:
        total = pss = 0
        try:
            procs = [self._p] + self._p.children(recursive=True)
        except self._psutil.NoSuchProcess:
            return 0, 0
        for p in procs:
            try:
                rss = p.memory_info().rss
                pss += getattr(p.memory_full_info(), "pss", rss) if self.pss else rss
            except (self._psutil.NoSuchProcess, self._psutil.AccessDenied):
                continue
            total += rss
            role = "main" if p.pid == self._p.pid else "worker"
            self.by_role[role] = max(self.by_role.get(role, 0), rss)
        return total, pss

    def _update(self):
        rss, pss = self._sample()
        self.peak, self.peak_pss = max(self.peak, rss), max(self.peak_pss, pss)

    def _run(self):
        while not self._stop.is_set():
            self._update()
            self._stop.wait(self.period)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self._update()


def _key(cfg: dict) -> str:
    return "-".join(str(cfg[k]).replace(",", "_") for k in sorted(cfg))


def make_campaign(cfg: dict, cache: Path) -> Path:
    key = _key(cfg)
    camp = cache / f"campaign-{key}"
    if (camp / "campaign.toml").is_file():
        return camp
    print(f"synthesising the campaign into {camp} (once) ...", flush=True)
    t0 = time.perf_counter()
    rc = cli(["synth", str(camp), "--joints", cfg["joints"], "--loads", cfg["loads"], "--vmax", cfg["vmax"],
              "--reps", str(cfg["reps"]), "--duration", str(cfg["duration"]), "--marker-rate", str(cfg["rate"]),
              "--log-rate", str(cfg["rate"]), "--markers-per-link", "3,3", "--effect", "stribeck",
              "--seed", "7", "--truth", str(cache / f"truth-{key}"), "--overwrite", "--quiet"])
    if rc != 0:
        raise SystemExit(f"synth failed ({rc})")
    print(f"  synthesised in {time.perf_counter() - t0:.0f} s", flush=True)
    return camp


def run_once(camp: Path, out: Path, settings: StudySettings, workers: int | None = None,
             client=None) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    if client is not None:
        from ident.study.executor import DaskExecutor

        ex = DaskExecutor(client=client, progress=False)
    else:
        ex = make_executor(workers, progress=False)
    try:
        with PeakRSS() as mem:
            t0, c0 = time.perf_counter(), time.process_time()
            res = Study(settings, ex, progress=False).run(camp, out)
            wall, main_cpu = time.perf_counter() - t0, time.process_time() - c0
    finally:
        ex.close()
    return {"wall": wall, "peak_gb": mem.peak / 1e9, "stages": res.to_dict()["stages"], "errors": res.errors,
            "verdicts": res.verdicts, "load": os.getloadavg()[0], "main_cpu": main_cpu,
            "role_gb": {k: v / 1e9 for k, v in mem.by_role.items()}}


def memory_scaling(args) -> int:
    """Peak resident memory of an N-trial study and of a ``scale`` x N-trial one of the same
    design (more repetitions of every condition), through the real pipeline. Each study runs
    in a fresh child process of this invocation (``--mem-run``): a worker forked from a main
    process that an earlier study grew would count that study's pages again. The peak is the
    largest sum over the child and its workers of the resident set sizes (RSS; pages shared
    after the fork count once per process) and of the proportional set sizes (PSS: shared
    pages split between the processes); the ratio is printed against the 1.2 goal."""
    import json
    import subprocess

    joints = args.mem_joints.split(",")
    per_rep = len(joints) * 2 * 3            # 2 loads x 3 speed ranges
    if args.trials % per_rep:
        raise SystemExit(f"--trials must be a multiple of {per_rep} (joints x 2 loads x 3 speeds)")
    peaks = {}
    for n in (args.trials, args.scale * args.trials):
        cfg = dict(FULL, joints=args.mem_joints, reps=n // per_rep, duration=args.duration)
        camp = make_campaign(cfg, args.cache)
        out = args.cache / f"out-{_key(cfg)}-mem"
        res = args.cache / f"mem-{_key(cfg)}.json"
        cmd = [sys.executable, __file__, "--mem-run", str(camp), str(out), str(res),
               "--mem-workers", str(args.mem_workers)] + (
            [] if args.diagnosis_reps is None else ["--diagnosis-reps", str(args.diagnosis_reps)])
        child = subprocess.Popen(cmd)
        with PeakRSS(pid=child.pid, pss=True) as mem:
            rc = child.wait()
        if rc != 0:
            raise SystemExit(f"the {n}-trial study failed ({rc})")
        r = json.loads(res.read_text())
        peaks[n] = (mem.peak, mem.peak_pss)
        roles = ", ".join(f"{k} {v / 1e9:.2f} GB" for k, v in sorted(mem.by_role.items()))
        print(f"{n:5d} trials of {args.duration:g} s, {args.mem_workers} worker(s), diagnosis reps "
              f"{_reps_label(args.diagnosis_reps)}: wall {r['wall']:.1f} s, peak RSS {mem.peak / 1e9:.2f} GB, "
              f"PSS {mem.peak_pss / 1e9:.2f} GB (largest single process RSS: {roles}); "
              f"load avg {os.getloadavg()[0]:.1f}" + (f"\n{'':6}errors: {r['errors']}" if r["errors"] else ""),
              flush=True)
        shutil.rmtree(out, ignore_errors=True)
    big, small = peaks[args.scale * args.trials], peaks[args.trials]
    for k, name in enumerate(("RSS", "PSS")):
        ratio = big[k] / small[k]
        print(f"peak {name} ratio {args.scale * args.trials} / {args.trials} trials: {ratio:.2f} "
              f"(goal <= {GOAL_MEM_RATIO:g}: {'met' if ratio <= GOAL_MEM_RATIO else 'NOT met'})", flush=True)
    return 0


def _reps_label(reps) -> str:
    return (f"within {DIAGNOSIS_SAMPLES} samples per joint (default)" if reps is None
            else "all" if reps == 0 else str(reps))


def _mem_run(args) -> int:
    """One study for :func:`memory_scaling`, in this (child) process; its figures to a JSON file."""
    import json

    camp, out, res = args.mem_run
    ex = make_executor(args.mem_workers, progress=False)
    try:
        t0 = time.perf_counter()
        r = Study(StudySettings(diagnosis_reps=args.diagnosis_reps), ex, progress=False).run(Path(camp), Path(out))
        wall = time.perf_counter() - t0
    finally:
        ex.close()
    Path(res).write_text(json.dumps({"wall": wall, "errors": r.errors}))
    return 0


def resume(camp: Path, out: Path, settings: StudySettings, workers: int) -> float:
    ex = make_executor(workers, progress=False)
    try:
        t0 = time.perf_counter()
        res = Study(settings, ex, progress=False).run(camp, out)
        wall = time.perf_counter() - t0
    finally:
        ex.close()
    assert all(st["computed"] == 0 for st in res.stages.values()), res.stages
    return wall


def show(name: str, r: dict, base: float | None, workers: int, out=print):
    st = ", ".join(f"{k} {v['seconds']:.1f}s" for k, v in r["stages"].items())
    ratio = f"  speed-up vs 1 worker x{base / r['wall']:.2f}" if base else ""
    # parallel efficiency of the mapped stages: the items' own wall times (measured in the
    # workers) over workers x stage wall time; near 1 = the seam keeps every worker busy, even
    # when other load on a shared machine slows every item down
    # (the diagnosis' items are queued behind the fits': the two stages share one span)
    eff = []
    for ks in (("mocap",), ("fits", "diagnosis")):
        vs = [r["stages"].get(k, {}) for k in ks]
        sec, work = sum(v.get("seconds", 0) for v in vs), sum(v.get("work_s", 0) for v in vs)
        if sec and work:
            eff.append(f"{' + '.join(ks)} {work / (workers * sec):.2f}")
    cpu = []
    for k in ("mocap", "fits", "diagnosis"):
        v = r["stages"].get(k, {})
        if v.get("computed") and v.get("cpu_s"):
            cpu.append(f"{k} {v['cpu_s'] / v['computed']:.2f} s/item ({v['cpu_s']:.1f} s)")
    cpu.append(f"this process {r['main_cpu']:.1f} s")
    out(f"{name:<16} wall {r['wall']:7.1f} s  peak {r['peak_gb']:.2f} GB  load avg {r['load']:.1f}{ratio}\n"
          f"{'':16} {st}\n{'':16} parallel efficiency (items' time / (workers x stage time)): "
          f"{', '.join(eff)}\n{'':16} CPU time (items as the workers measured them; this process: the rest, everything with 1 worker): {', '.join(cpu)}"
          + (f"\n{'':16} errors: {r['errors']}" if r["errors"] else ""))


def _cpu(r: dict) -> float:
    """CPU seconds of a study: its own process plus the mapped items as the workers measured them."""
    return r["main_cpu"] + sum(r["stages"].get(k, {}).get("cpu_s", 0.0) for k in ("mocap", "fits", "diagnosis"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small campaign (a few minutes at most)")
    ap.add_argument("--workers", default="1,2", help="local worker counts to time (default 1,2)")
    ap.add_argument("--dask", action="store_true", help="also run on a 2-worker Dask LocalCluster")
    ap.add_argument("--no-resume", action="store_true", help="skip the resume (all up to date) timing")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "jointlab-bench-study")
    ap.add_argument("--memory", action="store_true",
                    help="only the memory scaling: an N-trial and a 10N-trial study, peak RSS ratio")
    ap.add_argument("--trials", type=int, default=180, help="--memory: N (default 180)")
    ap.add_argument("--scale", type=int, default=10, help="--memory: the larger study's factor (default 10)")
    ap.add_argument("--duration", type=float, default=20.0,
                    help="--memory: trial length in s (default 20; shorter keeps a 10x study quick)")
    ap.add_argument("--mem-joints", default="1,2,3,4,5,6", help="--memory: joints (default 1-6)")
    ap.add_argument("--diagnosis-reps", type=int, default=None,
                    help="--memory: the diagnosis reads the first R repetitions per condition (0: all; "
                         "default: the study's default, the most within its sample budget)")
    ap.add_argument("--mem-workers", type=int, default=2, help="--memory: local workers (default 2)")
    ap.add_argument("--against", type=Path, metavar="TREE",
                    help="also run the 2-worker study with this jointlab checkout (a before-figure)")
    ap.add_argument("--results", type=Path, metavar="FILE", help="also write what is printed to FILE")
    ap.add_argument("--mem-run", nargs=3, metavar=("CAMPAIGN", "OUT", "RESULT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.mem_run:
        return _mem_run(args)
    if args.memory:
        args.cache.mkdir(parents=True, exist_ok=True)
        return memory_scaling(args)
    cfg = QUICK if args.quick else FULL
    args.cache.mkdir(parents=True, exist_ok=True)
    camp = make_campaign(cfg, args.cache)
    out = Tee(args.results)
    out("# python benchmarks/study.py " + " ".join(argv if argv is not None else sys.argv[1:]))
    n_trials = len(cfg["joints"].split(",")) * len(cfg["loads"].split(",")) * len(cfg["vmax"].split(",")) * cfg["reps"]
    out(f"load average before: {os.getloadavg()[0]:.1f} (other work on the machine skews the ratios)")
    out(f"campaign: {n_trials} trials of {cfg['duration']:g} s, joints {cfg['joints']}, loads {cfg['loads']}, "
        f"speeds {cfg['vmax']}, {cfg['reps']} reps, {cfg['rate']:g} Hz; {os.cpu_count()} cores")
    settings = StudySettings()
    results, infos = {}, [info_pass(camp)]
    out(f"baseline: jointlab info over the campaign: wall {infos[0]['wall']:.2f} s, CPU {infos[0]['cpu']:.2f} s")
    base = None
    for w in [int(x) for x in args.workers.split(",") if x.strip()]:
        r = run_once(camp, args.cache / f"out-{_key(cfg)}-w{w}", settings, workers=w)
        results[w] = r
        if w == 1:
            base = r["wall"]
        show(f"{w} worker(s)", r, base if w != 1 else None, w, out)
        infos.append(info_pass(camp))
        out(f"baseline: jointlab info again: wall {infos[-1]['wall']:.2f} s, CPU {infos[-1]['cpu']:.2f} s")
    against = None
    if args.against is not None:
        against = run_against(args.against, camp, args.cache / f"out-{_key(cfg)}-against", 2)
        st = ", ".join(f"{k} {v['seconds']:.1f}s" for k, v in against["stages"].items())
        out(f"{'--against':<16} wall {against['wall']:7.1f} s with {args.against} (2 workers)\n{'':16} {st}"
            + (f"\n{'':16} errors: {against['errors']}" if against["errors"] else ""))
        infos.append(info_pass(camp))
        out(f"baseline: jointlab info again: wall {infos[-1]['wall']:.2f} s, CPU {infos[-1]['cpu']:.2f} s")
    if args.dask:
        try:
            import distributed
        except ImportError:
            out("dask: not installed (pip install 'jointlab[dask]')")
        else:
            with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                          dashboard_address=None) as cluster, \
                    distributed.Client(cluster) as client:
                r = run_once(camp, args.cache / f"out-{_key(cfg)}-dask", settings, client=client)
            show("dask 2 workers", r, base, 2, out)
            if 2 in results:
                out(f"{'':16} dask / pool wall ratio {r['wall'] / results[2]['wall']:.2f}")
    if not args.no_resume and results:
        w = max(results)
        t = resume(camp, args.cache / f"out-{_key(cfg)}-w{w}", settings, w)
        out(f"resume (all up to date, {w} workers): {t:.1f} s = {100 * t / results[w]['wall']:.1f} % "
            "of the first run")
    info_wall = sum(i["wall"] for i in infos) / len(infos)
    info_cpu = sum(i["cpu"] for i in infos) / len(infos)
    out(f"baseline (mean of {len(infos)} info passes): wall {info_wall:.2f} s, CPU {info_cpu:.2f} s")
    if 2 in results:
        r = results[2]
        cpu = _cpu(r)
        ratio = r["wall"] / info_wall
        out(f"2 workers / info pass: wall {ratio:.2f}x; CPU (this process + the workers' items) "
            f"{cpu:.1f} s = {cpu / info_cpu:.2f}x the info pass's CPU")
        if against is not None:
            out(f"2 workers, this tree / {args.against}: wall {r['wall']:.1f} / {against['wall']:.1f} s = "
                f"{r['wall'] / against['wall']:.2f} (the other tree: {against['wall'] / info_wall:.2f}x info); "
                f"CPU {cpu:.1f} / {_cpu(against):.1f} s = {cpu / _cpu(against):.2f}; fits items' CPU "
                f"{r['stages']['fits'].get('cpu_s', 0):.1f} / {against['stages']['fits'].get('cpu_s', 0):.1f} s")
        if not args.quick:
            out(f"goal (issue 47): {GOAL47_S:.0f} s on 2 workers, at the issue's 45 s = 7x info: "
                f"<= {ISSUE47_INFO_RATIO:.1f}x info -> {ratio:.2f}x "
                f"({'met' if ratio <= ISSUE47_INFO_RATIO else 'NOT met'}); absolute {r['wall']:.1f} s "
                f"({'met' if r['wall'] <= GOAL47_S else 'NOT met'}; load average {r['load']:.1f})")
            out(f"goal: {GOAL_S:.0f} s on 2 cores -> {r['wall']:.1f} s ({'met' if r['wall'] < GOAL_S else 'NOT met'}); "
                f"peak {GOAL_GB:.0f} GB -> {r['peak_gb']:.2f} GB ({'met' if r['peak_gb'] < GOAL_GB else 'NOT met'})")
            out(f"goal (issue 13): {GOAL13_S:.0f} s on 2 workers -> {r['wall']:.1f} s "
                f"({'met' if r['wall'] <= GOAL13_S else 'NOT met'}; load average {r['load']:.1f})")
    out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
