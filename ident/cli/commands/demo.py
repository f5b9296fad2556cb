"""``jointlab demo --out DIR``: the study (``jointlab study``) of the bundled demo campaign
``fixtures/demo`` (a simulated PA10 joint-5 campaign with a withheld Stribeck effect, made by
``jointlab synth``; see fixtures/demo/REGENERATE.md)."""
from __future__ import annotations

from pathlib import Path

from mocap.io.errors import InputError

from ident.cli.main import add_common
from ident.cli.commands.study import add_study_options, run_from_args

REGENERATE = ("jointlab synth fixtures/demo --effect stribeck --magnitude 1.0 --seed 1 --joints 5 "
              "--loads 0,3.373 --vmax 0.5,1.0 --reps 3 --duration 4.0 --kinds excitation --robot pa10 "
              "--marker-rate 100.0 --log-rate 200.0 --markers-per-link 3 "
              "--truth fixtures/demo-truth/demo --overwrite")


def demo_campaign() -> Path:
    """The bundled demo campaign folder (the repository's fixtures/demo)."""
    return Path(__file__).resolve().parents[3] / "fixtures" / "demo"


def register(sub):
    p = sub.add_parser("demo", help="run the whole study on the bundled demo campaign (fixtures/demo)")
    add_common(p, out_required=True)
    add_study_options(p)
    return p


def run(args) -> int:
    camp = demo_campaign()
    if not (camp / "campaign.toml").is_file():
        raise InputError("the bundled demo campaign is missing (jointlab demo needs the repository's "
                         "fixtures/ folder, e.g. an editable install: pip install -e .); regenerate it "
                         f"from the repository root with: {REGENERATE}", path=camp / "campaign.toml")
    return run_from_args(args, camp)
