"""The study's per-trial fit items and per-condition figures, in this process (issue 47, the
180-trial study's CPU): a profile of the fit items, and two ratios timed in the same run.

The trials are those of ``benchmarks/study.py``'s full campaign (synthesised there into its
cache; this script does not synthesise it) of one joint, with the link angles a study of that
campaign wrote (``--angles``, default the 2-worker study's ``angles/`` in the same cache; without
them the motor angle stands in, as the study does for a trial without angles). Each item is
what ``ident.study.study._run_fit_job`` runs for a trial: ``fit_trial_joint`` (signals, the
cv/stribeck/hyperbolic fits of eq. 2-4, the input checks, the plot samples) and its record.

``--profile``: cProfile of the items, timed in CPU seconds (top entries by own time and cumulative,
``--top``).
``--trim``: the items' CPU when the heap is handed back after every item (``malloc_trim``, what a
pool worker did) against only above ``TRIM_ABOVE_BYTES`` free (what it does now), alternating
blocks, best and median of ``--repeats``; page faults per item.
``--breakdown``: a whole 2-worker study of the campaign (into a temporary folder), this
process's CPU by function (wrappers summing ``time.process_time`` of the main thread's calls;
nested entries overlap; the recording's thread measured by its own ``time.thread_time``) and
the whole process's (every thread: the executor's result thread, the recording's).
``--pool``: the same comparison with the items run by a 2-worker pool (the items' own CPU).
``--plots``: one joint's per-condition friction figures (``fits/plots/``) each drawn on a new
figure (``plot_friction_vs_speed``, as before) against all drawn on one figure
(``plot_friction_vs_speed_many``), alternating, and that the PNGs are the same bytes.

    python benchmarks/study_items.py --profile --trim --plots [--joint 5] [--trials 30] [--breakdown]
"""
from __future__ import annotations

import argparse
import cProfile
import dataclasses
import io
import os
import pstats
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ident.study import executor as E  # noqa: E402
from ident.study.study import StudySettings, _FitJob, _run_fit_job  # noqa: E402
from ident.thesis.campaign_fit import campaign_tasks  # noqa: E402
from mocap.io.campaign import load_campaign  # noqa: E402

KEY = "20.0-1_2_3_4_5_6-0_3.373-200.0-5-0.3_0.6_1.0"     # benchmarks/study.py's FULL campaign


def _field(item, name):
    """A fit item's field (a dict before the study's result types, a FitItem after)."""
    return item[name] if isinstance(item, dict) else getattr(item, name)


def _jobs(camp_dir: Path, angles: Path | None, joint: int, n: int, tmp: Path, keep_plot: bool):
    camp = load_campaign(camp_dir)
    trials = tuple(t for t in camp.trials if list(t.joints) == [joint])[:n]
    camp = dataclasses.replace(camp, trials=trials)
    s = StudySettings()
    tasks, _ = campaign_tasks(camp, None, s.models, s.n_starts, s.seed, s.sync)
    jobs = []
    for t in tasks:  # loop over the trials' tasks (one joint each)
        a = None if angles is None else angles / f"{t.trial}.csv"
        t = dataclasses.replace(t, angles=str(a) if a is not None and a.is_file() else None)
        jobs.append(_FitJob(t.trial, (t,), str(tmp / f"{t.trial}.json"), str(tmp), "bench", keep_plot=keep_plot))
    return jobs


def profile(jobs, top: int) -> None:
    pr = cProfile.Profile(time.process_time)     # CPU seconds: steadier than wall on a loaded machine
    c0 = time.process_time()
    pr.enable()
    out = [_run_fit_job(j) for j in jobs]
    pr.disable()
    cpu = time.process_time() - c0
    print(f"profile: {len(jobs)} fit items, {cpu:.2f} s CPU under the profiler "
          f"({sum(_field(o, 'cpu_s') for o in out) / len(out):.3f} s per item as the items measure it)")
    for key in ("tottime", "cumulative"):  # loop over the two orders
        buf = io.StringIO()
        pstats.Stats(pr, stream=buf).sort_stats(key).print_stats(top)
        print("\n".join(line for line in buf.getvalue().splitlines() if line.strip()))


def trim(jobs, repeats: int) -> None:
    _run_fit_job(jobs[0])                      # imports and caches out of the timing
    res = {"every item": [], "above threshold": []}
    for r in range(repeats):  # loop over repeats, the order alternating
        order = ("every item", "above threshold") if r % 2 == 0 else ("above threshold", "every item")
        for mode in order:  # loop over the two modes
            above = 0 if mode == "every item" else E.TRIM_ABOVE_BYTES
            r0, c0 = resource.getrusage(resource.RUSAGE_SELF), time.process_time()
            for j in jobs:  # loop over the items, as a worker runs them
                if above:
                    E._run_and_release(_run_fit_job, j)
                else:
                    _run_fit_job(j)
                    E.release_free_memory()
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            res[mode].append((time.process_time() - c0, (r1.ru_minflt - r0.ru_minflt) / len(jobs),
                              (r1.ru_stime - r0.ru_stime) / len(jobs)))
    for mode, v in res.items():  # loop over the two modes
        cpu = [c for c, _, _ in v]
        print(f"trim {mode:16s}: CPU per {len(jobs)} items best {min(cpu):.2f} s, median "
              f"{statistics.median(cpu):.2f} s; per item: page faults {statistics.median(f for _, f, _ in v):.0f}, "
              f"system CPU {1e3 * statistics.median(st for _, _, st in v):.1f} ms")
    a = statistics.median(c for c, _, _ in res["above threshold"])
    b = statistics.median(c for c, _, _ in res["every item"])
    print(f"trim: above threshold / every item (medians) = {a / b:.3f}")


def pool(jobs, repeats: int) -> None:
    """The items through a 2-worker pool, as the study runs them: the items' own CPU (``cpu_s``)
    summed, with the trim after every item (``TRIM_ABOVE_BYTES = 0``, as before) against the
    threshold, a fresh pool per run, alternating."""
    default = E.TRIM_ABOVE_BYTES
    res = {"every item": [], "above threshold": []}
    try:
        for r in range(repeats):  # loop over repeats, the order alternating
            order = tuple(res) if r % 2 == 0 else tuple(reversed(tuple(res)))
            for mode in order:  # loop over the two modes
                E.TRIM_ABOVE_BYTES = 0 if mode == "every item" else default   # read by the forked workers
                ex = E.make_executor(2, progress=False)
                try:
                    out = ex.map(_run_fit_job, jobs, "fits")
                finally:
                    ex.close()
                res[mode].append(sum(_field(o, "cpu_s") for o in out))
    finally:
        E.TRIM_ABOVE_BYTES = default
    for mode, v in res.items():  # loop over the two modes
        print(f"pool {mode:16s}: items' CPU for {len(jobs)} items, runs " + " ".join(f"{c:.2f}" for c in v)
              + f" s; median {statistics.median(v):.2f} s")
    print(f"pool: above threshold / every item (medians) = "
          f"{statistics.median(res['above threshold']) / statistics.median(res['every item']):.3f}")


def plots(jobs, repeats: int, out: Path) -> None:
    from ident.thesis import tables
    from ident.thesis.campaign_fit import FitsResult

    entries = tuple(e for j in jobs for e in _field(_run_fit_job(j), "entries"))
    done, figures = set(), []
    # loop over the entries, the first repetition of each condition first
    for e in sorted(entries, key=lambda e: (-e.task.load_kg, -e.task.vmax_frac, e.task.repetition)):
        key = (e.task.load_kg, e.task.vmax_frac)
        if key not in done and e.plot:
            done.add(key)
            figures.append((f"f{len(figures)}.png", e.plot["qd"], e.plot["f_measured"],
                            {m: f.friction() for m, f in e.fits.items()}, f"condition {key}"))
    FitsResult(entries, ("cv",)).write_plots(out / "warm")      # fonts and caches out of the timing
    res = {"one figure each": [], "one figure": []}
    for r in range(repeats):  # loop over repeats, the order alternating
        order = tuple(res) if r % 2 == 0 else tuple(reversed(tuple(res)))
        for mode in order:  # loop over the two modes
            c0 = time.process_time()
            if mode == "one figure":
                tables.plot_friction_vs_speed_many([(out / ("many-" + n), *rest) for n, *rest in figures])
            else:
                for n, *rest in figures:  # loop over the figures, each on a new one
                    tables.plot_friction_vs_speed(out / ("each-" + n), *rest)
            res[mode].append(time.process_time() - c0)
    same = all((out / ("many-" + n)).read_bytes() == (out / ("each-" + n)).read_bytes() for n, *_ in figures)
    for mode, v in res.items():  # loop over the two modes
        print(f"plots {mode:16s}: CPU for {len(figures)} figures best {min(v):.3f} s, "
              f"median {statistics.median(v):.3f} s")
    print(f"plots: one figure / one figure each (medians) = "
          f"{statistics.median(res['one figure']) / statistics.median(res['one figure each']):.3f}; "
          f"PNGs identical: {same}")


def breakdown(camp_dir: Path, out: Path) -> None:
    import functools
    import threading

    import ident.study.study as S

    acc: dict = {}

    def wrap(owner, name, label=None):
        fn = getattr(owner, name)

        @functools.wraps(fn)
        def w(*a, **k):
            if threading.current_thread() is not threading.main_thread():
                return fn(*a, **k)
            c0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                acc[label or name] = acc.get(label or name, 0.0) + time.process_time() - c0
        setattr(owner, name, w)

    saved = []
    for owner, name, label in [(S.Study, m, None) for m in (
            "_calib", "_mocap", "_fits_start", "_fits_finish", "_draw_joint_fits", "_diagnosis_start",
            "_diagnosis_finish", "_report", "_fits_commit")] + [
            (S, "campaign_tasks", None), (S, "write_study_plots", None),
            (S.FitsResult, "write_plots", "FitsResult.write_plots (fits/plots/)"),
            (S.FitResult, "write", "FitResult.write (fits.json, tables)"), (S._Hasher, "file", "hashing inputs"),
            (S._StudyRecording, "finish", "recording: finish")]:
        if hasattr(owner, name):
            saved.append((owner, name, getattr(owner, name)))
            wrap(owner, name, label)
    log_inputs = S._log_inputs

    def timed_log_inputs(*a, **k):
        c0 = time.thread_time()
        try:
            return log_inputs(*a, **k)
        finally:
            key = "recording: inputs (its thread)"
            acc[key] = acc.get(key, 0.0) + time.thread_time() - c0
    S._log_inputs = timed_log_inputs
    ex = E.make_executor(2, progress=False)
    c0, t0, m0 = time.process_time(), time.perf_counter(), time.thread_time()
    try:
        r = S.Study(S.StudySettings(), ex, progress=False).run(camp_dir, out)
        threads = _thread_cpu()            # before the pool's threads end with it
    finally:
        ex.close()
        S._log_inputs = log_inputs
        for owner, name, fn in saved:  # loop over the wrapped functions: restored
            setattr(owner, name, fn)
    print(f"breakdown: the study's process {time.process_time() - c0:.2f} s CPU (all threads; main thread "
          f"{time.thread_time() - m0:.2f} s), wall {time.perf_counter() - t0:.1f} s; errors {sorted(r.errors)}")
    for k, v in r.stages.items():  # loop over stages
        g = (lambda n: v.get(n, 0)) if isinstance(v, dict) else (lambda n: getattr(v, n, 0))
        print(f"  stage {k}: {g('computed')} computed, {g('seconds'):.1f} s, items' CPU {g('cpu_s'):.1f} s")
    for k, v in sorted(acc.items(), key=lambda kv: -kv[1]):  # loop over the functions, costliest first
        print(f"  {k:40s} {v:7.2f} s")
    if threads:
        print("  threads alive at the study's end, CPU (threading name, or the OS name): " + ", ".join(
            f"{name} {cpu:.2f} s" for name, cpu in sorted(threads.items(), key=lambda kv: -kv[1]) if cpu >= 0.05))


def _thread_cpu() -> dict:
    """CPU seconds of this process's live threads by name: Python threads by their
    ``threading`` name (``time.pthread_getcpuclockid``), the others by their OS name (/proc)."""
    import threading

    out: dict = {}
    seen = set()
    for t in threading.enumerate():  # loop over the Python threads
        try:
            cpu = time.clock_gettime(time.pthread_getcpuclockid(t.ident))
        except (AttributeError, OSError, TypeError):
            continue
        seen.add(t.native_id)
        out[t.name] = out.get(t.name, 0.0) + cpu
    tick = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    for task in Path("/proc/self/task").glob("*"):  # loop over the other live threads (Linux)
        try:
            if int(task.name) in seen:
                continue
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, ValueError):
            continue
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "jointlab-bench-study")
    ap.add_argument("--angles", type=Path, help="link angles folder (default: the 2-worker study's in --cache)")
    ap.add_argument("--joint", type=int, default=5)
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--trim", action="store_true")
    ap.add_argument("--plots", action="store_true")
    ap.add_argument("--breakdown", action="store_true")
    ap.add_argument("--pool", action="store_true")
    args = ap.parse_args(argv)
    camp = args.cache / f"campaign-{KEY}"
    if not (camp / "campaign.toml").is_file():
        raise SystemExit(f"{camp}: no campaign; run benchmarks/study.py first (it synthesises it)")
    angles = args.angles or args.cache / f"out-{KEY}-w2" / "angles"
    if not angles.is_dir():
        print(f"no angles folder {angles}: the motor angle stands in for the link angle")
        angles = None
    print(f"# python benchmarks/study_items.py {' '.join(argv if argv is not None else sys.argv[1:])}")
    print(f"load average {os.getloadavg()[0]:.1f}; joint {args.joint}, {args.trials} trials; angles {angles}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.profile:
            profile(_jobs(camp, angles, args.joint, args.trials, tmp, False), args.top)
        if args.trim:
            trim(_jobs(camp, angles, args.joint, args.trials, tmp, False), args.repeats)
        if args.pool:
            pool(_jobs(camp, angles, args.joint, args.trials, tmp, False), args.repeats)
        if args.plots:
            plots(_jobs(camp, angles, args.joint, args.trials, tmp, True), args.repeats, tmp / "png")
        if args.breakdown:
            breakdown(camp, tmp / "study")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
