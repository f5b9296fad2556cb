"""Issue 14: does the verdict on a multi-joint record change with the segmentation?

Each record is diagnosed through the CLI's path for multi-joint records
(``jointlab diagnose CAMPAIGN``; ``n_segments`` through ``diagnose_records``, which the CLI
calls) under the segmentations of ``tests/segmentation_world.py``: one file; the same record
cut into 2, 3 or 5 files at arbitrary instants (a logger that rotates its files), with and
without 0.1 s of samples lost at each cut; cropped by a few seconds at the start or the end;
6, 10, 20 or 40 held-out segments instead of the motion cycles. Records:

* the real Staubli TX40 record (``fixtures/real/tx40``, 9 s, six joints moving together);
* a 7-joint record of ``fixtures/arm7`` made with pinocchio (30 s), without a withheld effect,
  with a squared-secant Stribeck drop on joint 2, and with a hyperbolic presliding deficit on
  joint 2 (forms written in ``tests/segmentation_world.py``, not taken from the candidates).

Prints, per record, a table joint x segmentation: verdict (``*``: insufficient data), held-out
nominal RMS (N m) and the number of blocks of the sign-flip test, then the segmentations whose
verdict differs from the one-file verdict ("flips").

    python benchmarks/segmentation.py [--quick] [--json FILE]

``--quick``: joint 2 of the 7-joint records only (TX40 in full).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path[:0] = [str(REPO), str(REPO / "tests")]

TX40 = REPO / "fixtures" / "real" / "tx40"


def table(name: str, res: dict) -> str:
    segs = list(res)
    joints = sorted({j for row in res.values() for j in row}, key=lambda j: (len(j), j))
    w = max(len(s) for s in segs)
    lines = [f"## {name}", f"{'segmentation':<{w}} | " + " | ".join(f"joint {j:<22}" for j in joints)]
    for s in segs:
        cells = []
        for j in joints:
            v = res[s].get(j)
            mark = "*" if v and v[3] == "insufficient_data" else ""
            cells.append(f"{v[0] + mark:<14} {v[1]:6.3f} {v[2]:3d}" if v else f"{'-':<28}")
        lines.append(f"{s:<{w}} | " + " | ".join(cells))
    ref = res[segs[0]]
    flips = [f"{s}: joint {j} {ref[j][0]} -> {res[s].get(j, ('missing',))[0]}"
             for s in segs[1:] for j in joints if j in ref and res[s].get(j, ("missing",))[0] != ref[j][0]]
    lines.append("cells: verdict (* = verdict_status insufficient_data: the sign-flip test cannot reach "
                 "its level with these blocks), held-out nominal RMS N m, blocks of the test")
    lines.append("flips: " + ("; ".join(flips) if flips else "none"))
    crop = lambda s: s.startswith("crop")  # noqa: E731
    for what, use in (("contiguous file cuts and n_segments", lambda s: "lost" not in s and not crop(s)),
                      ("also the cuts that lose 0.1 s", lambda s: not crop(s))):
        spread = [(j, [res[s][j][1] for s in segs if j in res[s] and use(s)]) for j in joints]
        lines.append(f"held-out nominal RMS spread (max/min - 1), {what}: "
                     + ", ".join(f"j{j} {max(v) / min(v) - 1:.1%}" for j, v in spread))
    return "\n".join(lines)


def main(argv=None) -> int:
    from segmentation_world import arm7_campaign, diagnose_segmentations

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        runs = [("TX40 (real, fixtures/real/tx40)", TX40, range(1, 7))]
        for label, kw in (("arm7, no withheld effect", dict(effect_joint=None)),
                          ("arm7, squared-secant Stribeck on joint 2", dict(effect_joint=2, effect="stribeck")),
                          ("arm7, hyperbolic presliding on joint 2",
                           dict(effect_joint=2, effect="presliding"))):
            src = tmp / label.split(",")[1].strip().split()[0] / "src"
            arm7_campaign(src, **kw)
            runs.append((label, src, [2] if a.quick else range(1, 8)))
        for k, (label, src, joints) in enumerate(runs):
            c0, w0 = time.process_time(), time.perf_counter()
            res = diagnose_segmentations(src, tmp / f"work-{k}", joints)
            print(table(label, res))
            print(f"({time.process_time() - c0:.1f} s CPU, {time.perf_counter() - w0:.1f} s wall, "
                  f"shared 2-core machine)\n", flush=True)
            out[label] = res
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
