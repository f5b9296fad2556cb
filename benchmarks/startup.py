"""Start-up time of the command line: ``jointlab --help`` (median wall time of N runs) and the
summed ``python -X importtime`` of ``import ident.cli.main`` and of building the parser, for this
tree and, with ``--base DIR``, another checkout of jointlab (runs alternate between the trees so
that a change of machine load hits both alike).

    python benchmarks/startup.py                       # this tree
    git archive <commit> | tar -x -C /tmp/base && python benchmarks/startup.py --base /tmp/base
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CODES = {"import ident.cli.main": "import ident.cli.main",
         "build_parser": "from ident.cli.main import build_parser; build_parser()"}


def _env(tree: Path) -> dict:
    return dict(os.environ, PYTHONPATH=str(tree))


def help_time(tree: Path) -> float:
    """Wall time (s) of one ``python -m ident.cli --help`` run against ``tree``."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "ident.cli", "--help"], env=_env(tree), check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def import_ms(tree: Path, code: str) -> float:
    """The sum of the self times (ms) ``-X importtime`` reports for ``code`` against ``tree``."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", code], env=_env(tree),
                         capture_output=True, text=True, check=True).stderr
    return sum(int(m) for m in re.findall(r"import time:\s+(\d+) \|", err)) / 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, help="another jointlab checkout to compare against")
    ap.add_argument("-n", type=int, default=15, help="runs per tree (default 15)")
    args = ap.parse_args(argv)
    trees = {"base": args.base.resolve()} if args.base else {}
    trees["this"] = ROOT
    walls = {k: [] for k in trees}
    imports = {k: {c: [] for c in CODES} for k in trees}
    for _ in range(args.n):
        for k, tree in trees.items():
            walls[k].append(help_time(tree))
            for c, code in CODES.items():
                imports[k][c].append(import_ms(tree, code))
    for k, tree in trees.items():
        parts = ", ".join(f"{c} {statistics.median(v):.0f} ms" for c, v in imports[k].items())
        print(f"{k} ({tree}): --help median {1e3 * statistics.median(walls[k]):.0f} ms "
              f"(min {1e3 * min(walls[k]):.0f}); importtime: {parts}")
    if args.base:
        ratio = statistics.median(walls["this"]) / statistics.median(walls["base"])
        print(f"--help this/base: {ratio:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
