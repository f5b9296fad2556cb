"""Issue 14: "the verdict on a multi-joint record does not change between any two reasonable
segmentations". A 7-joint record (fixtures/arm7, pinocchio's own inverse dynamics, every joint
moving) with and without a friction drop at low speed on joint 2 written in a form of its own
(``tests/segmentation_world.py``), diagnosed through the CLI's path for multi-joint records as
one file, cut into 2, 3 or 5 files at arbitrary instants (with and without samples lost at the
cuts), and with 6, 10, 20 or 40 held-out segments instead of the motion cycles."""
from __future__ import annotations

import json

import numpy as np
import pytest

from segmentation_world import SEGMENTATIONS, arm7_campaign, diagnose_segmentations, resegment

FILES = ["one file", "2 files", "3 files", "5 files", "3 files, 0.1 s lost", "5 files, 0.1 s lost"]
SEGMENTS = ["n_segments 6", "n_segments 10", "n_segments 20", "n_segments 40"]


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    out = {}
    for effect in ("stribeck", "none"):
        root = tmp_path_factory.mktemp(f"seg-{effect}")
        arm7_campaign(root / "src", duration=24.0, effect_joint=2 if effect == "stribeck" else None)
        out[effect] = diagnose_segmentations(root / "src", root, [2], FILES + SEGMENTS)
    return out


@pytest.mark.parametrize("effect", ["stribeck", "none"])
def test_verdict_does_not_depend_on_the_segmentation(tables, effect):
    tab = tables[effect]
    # one verdict per joint whatever the number of files (not one per file)
    assert all(set(row) == {"2"} for row in tab.values()), tab
    verdicts = {name: row["2"][0] for name, row in tab.items()}
    assert set(verdicts.values()) == {effect}, verdicts
    # ... and a conclusive one each time (not `insufficient data`)
    assert {row["2"][3] for row in tab.values()} == {"none" if effect == "none" else "effect"}, tab
    rms0 = tab["one file"]["2"][1]
    for name, row in tab.items():
        assert row["2"][1] == pytest.approx(rms0, rel=0.03), (name, row["2"][1], rms0)
    # the test's blocks stay the motion cycles: segments never cut one into two, and a cut file
    # adds at most one block per cut (the cycle it cut)
    n0 = tab["one file"]["2"][2]
    assert n0 >= 12
    for name in SEGMENTS + ["2 files", "3 files", "5 files"]:
        assert tab[name]["2"][2] == n0, (name, tab[name]["2"][2], n0)
    for name in ("3 files, 0.1 s lost", "5 files, 0.1 s lost"):
        assert n0 <= tab[name]["2"][2] <= n0 + len(SEGMENTATIONS[name][0]), (name, tab[name]["2"][2])


def test_pieces_of_one_record_are_joined_and_reported(tmp_path, capsys):
    """The CLI on a record cut into three files: one diagnosis per joint, the report names the
    pieces it joined; with samples lost at the cuts the pieces stay separate records."""
    from ident.cli import main

    arm7_campaign(tmp_path / "src", duration=8.0, effect_joint=None)
    for lost, joined in ((0.0, True), (0.1, False)):
        camp = resegment(tmp_path / "src", tmp_path / f"c{lost}", cuts=(0.3, 0.6), lost=lost)
        rc = main(["diagnose", str(camp), "--out", str(tmp_path / f"o{lost}"), "--joints", "3", "--json"])
        assert rc == 0
        summary = json.loads(capsys.readouterr().out)
        assert set(summary["joints"]) == {"3"}
        rec = json.loads((tmp_path / f"o{lost}" / "diagnosis.json").read_text())["joints"]["3"]["record"]
        assert rec["pieces"] == ([["part-1", "part-2", "part-3"]] if joined
                                 else [["part-1"], ["part-2"], ["part-3"]])


def test_motion_cycles_restart_in_each_trial():
    """A trial's cycles do not depend on the reversals of the trials before it."""
    from ident.gap.data import motion_cycles

    t = np.arange(0, 10, 0.01)
    qd = np.sin(2 * np.pi * 0.5 * t)                       # a reversal every second
    alone = motion_cycles(qd[300:])
    group = (np.arange(t.size) >= 300).astype(int)         # a first trial of 3 s: 3 reversals
    both = motion_cycles(qd, group=group)
    tail = both[300:] - both[300]
    assert np.array_equal(tail, alone - alone[0])
    # ungrouped, the odd count of the first part shifts the cycles of the second by half a cycle
    plain = motion_cycles(qd)[300:]
    assert not np.array_equal(plain - plain[0], alone - alone[0])
