"""The diagnosis on a campaign written by another program (plain text files, a different robot,
effect forms unlike the simulator's): the verdict must still name the withheld effect."""
import json

import pytest

from gap_synth import DRIVES, URDF, make_world
from ident.cli.main import main


def _write_foreign_campaign(root, trials, logs):
    """FORMAT v1 by hand: CSV logs with extra columns and blank cells, a TRC per trial with
    comma-free tab layout, no blank line 6, mm units, clocks that do not start at zero."""
    (root / "robot").mkdir(parents=True)
    (root / "robot" / "arm.urdf").write_text(URDF)
    (root / "robot" / "drives.toml").write_text(DRIVES)
    (root / "trials").mkdir()
    lines = ['format = 1', 'name = "foreign"', "", "[robot]", 'urdf = "robot/arm.urdf"',
             'drives = "robot/drives.toml"', "", "[markers]", 'link2 = ["M1", "M2", "M3"]', ""]
    for tr, lg in zip(trials, logs):
        csv = root / "trials" / f"{tr.id}.csv"
        with open(csv, "w") as fh:
            fh.write("time,tau_2,qm_2,temp_2,qm_1,tau_1\n")
            for k in range(lg.time.shape[0]):
                temp = "" if k % 97 == 0 else "31.5"
                fh.write(f"{lg.time[k]:.5f},{lg.tau[k, 1]:.6f},{lg.qm[k, 1]:.7f},{temp},0,0\n")
        trc = root / "trials" / f"{tr.id}.trc"
        n = 20
        head = ["PathFileType\t4\t(X/Y/Z)\tforeign.trc",
                "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
                f"100\t100\t{n}\t3\tmm\t100\t7\t{n}", "Frame#\tTime\tM1\t\t\tM2\t\t\tM3\t\t",
                "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3"]
        rows = [f"{k + 7}\t{lg.time[0] + k / 100:.3f}\t" + "\t".join(["100.0\t0.0\t500.0"] * 3) for k in range(n)]
        trc.write_text("\n".join(head + rows) + "\n")
        lines += ["[[trial]]", f'id = "{tr.id}"', "joints = [2]", f"load_kg = {tr.load_kg}",
                  f"vmax_frac = {tr.vmax_frac}", f"repetition = {tr.repetition}",
                  f'markers = "trials/{tr.id}.trc"', f'log = "trials/{tr.id}.csv"', 'operator = "someone"', ""]
    (root / "campaign.toml").write_text("\n".join(lines))


@pytest.mark.parametrize("effect", ["none", "stribeck", "position_ripple", "thermal_drift"])
def test_foreign_campaign(tmp_path, effect):
    rb, trials, logs, _, _ = make_world(tmp_path, effect, 1.0, seed=3, reps=3, duration=8.0)
    root = tmp_path / "campaign"
    _write_foreign_campaign(root, trials, logs)
    out = tmp_path / "out"
    assert main(["diagnose", str(root), "--out", str(out), "--no-markers"]) == 0
    rep = json.loads((out / "diagnosis.json").read_text())
    assert rep["joints"]["2"]["verdict"] == effect
