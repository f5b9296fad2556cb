"""campaign.toml (FORMAT.md): a hand-written campaign reads; each bad input gives one clear message."""
import numpy as np
import pytest

from ident.cli.main import main
from mocap.io.campaign import load_campaign, write_manifest
from mocap.io.errors import InputError
from two_link import URDF


DRIVES = """
[[joint]]
name = "joint1"
gear_ratio = 100.0
motor_inertia = 0.3
motor_viscous = 0.5
max_velocity = 1.0
max_torque = 50.0
encoder_resolution = 1.9e-4

[[joint]]
name = "joint2"
gear_ratio = 100.0
motor_inertia = 0.2
motor_viscous = 0.4
max_velocity = 2.0
max_torque = 30.0
encoder_resolution = 1.9e-4
"""


def _trc(labels, n=20, rate=100.0):
    head = ["PathFileType\t4\t(X/Y/Z)\tx.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"{rate}\t{rate}\t{n}\t{len(labels)}\tmm\t{rate}\t1\t{n}",
            "Frame#\tTime\t" + "\t\t\t".join(labels),
            "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, len(labels) + 1)), ""]
    rows = [f"{k + 1}\t{k / rate:.4f}\t" + "\t".join("1.0\t2.0\t3.0" for _ in labels) for k in range(n)]
    return "\n".join(head + rows) + "\n"


@pytest.fixture
def campaign_dir(tmp_path):
    root = tmp_path / "camp"
    (root / "robot").mkdir(parents=True)
    (root / "robot" / "arm.urdf").write_text(URDF)
    (root / "robot" / "drives.toml").write_text(DRIVES)
    labels = ["A1", "A2", "A3", "B1", "B2", "B3"]
    for sub, name in [("static", "pose-01"), ("calib", "joint-1"), ("calib", "joint-2"), ("trials", "t1")]:
        (root / sub).mkdir(exist_ok=True)
        (root / sub / f"{name}.trc").write_text(_trc(labels))
        (root / sub / f"{name}.csv").write_text(
            "time,qm_1,qm_2,tau_1,tau_2\n" + "".join(f"{k / 200:.4f},0,0,0,0\n" for k in range(40)))
    doc = {"format": 1, "name": "tiny",
           "robot": {"urdf": "robot/arm.urdf", "drives": "robot/drives.toml", "gravity": [0.0, 0.0, -9.81]},
           "markers": {"link1": ["A1", "A2", "A3"], "link2": ["B1", "B2", "B3"]},
           "static": [{"markers": "static/pose-01.trc", "log": "static/pose-01.csv"}],
           "calib": [{"joint": 1, "markers": "calib/joint-1.trc", "log": "calib/joint-1.csv"},
                     {"joint": 2, "markers": "calib/joint-2.trc", "log": "calib/joint-2.csv"}],
           "trial": [{"id": "t1", "joints": [2], "load_kg": 1.5, "vmax_frac": 0.5, "repetition": 2,
                      "markers": "trials/t1.trc", "log": "trials/t1.csv", "operator": "kept"}]}
    write_manifest(root / "campaign.toml", doc)
    return root


def test_reads_campaign(campaign_dir):
    c = load_campaign(campaign_dir)
    assert c.name == "tiny" and c.gravity == (0.0, 0.0, -9.81)
    assert c.markers == {"link1": ("A1", "A2", "A3"), "link2": ("B1", "B2", "B3")}
    assert [s.joint for s in c.calib] == [1, 2]
    t = c.trial("t1")
    assert t.joints == (2,) and t.load_kg == 1.5 and t.vmax_frac == 0.5 and t.repetition == 2
    assert t.kind == "excitation" and t.extra == {"operator": "kept"}
    robot = c.load_robot()
    assert robot.n == 2 and robot.drives[1].motor_inertia == 0.2
    np.testing.assert_allclose(robot.max_velocity, [1.0, 2.0])


def _edit(campaign_dir, old, new):
    p = campaign_dir / "campaign.toml"
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("old, new, needle", [
    ('markers = "trials/t1.trc"', 'markers = "trials/missing.trc"', "'trials/missing.trc' not found"),
    ("format = 1", "format = 2", "unsupported campaign format 2"),
    ('kind', 'kind', None),
])
def test_bad_manifest_messages(campaign_dir, old, new, needle):
    if needle is None:
        _edit(campaign_dir, "repetition = 2", 'repetition = 2\nkind = "sprint"')
        needle = "kind 'sprint' is not one of"
    else:
        _edit(campaign_dir, old, new)
    with pytest.raises(InputError) as e:
        load_campaign(campaign_dir)
    assert needle in str(e.value) and "campaign.toml" in str(e.value)


def test_link_absent_from_urdf(campaign_dir):
    _edit(campaign_dir, "link2 = ", "link9 = ")
    with pytest.raises(InputError, match="link 'link9', which is not in the URDF"):
        load_campaign(campaign_dir).load_robot()


def test_drive_count_disagrees_with_urdf(campaign_dir):
    p = campaign_dir / "robot" / "drives.toml"
    p.write_text(DRIVES.split("[[joint]]\nname = \"joint2\"")[0])
    with pytest.raises(InputError, match="drives describe 1 joints but the URDF has 2"):
        load_campaign(campaign_dir).load_robot()


def test_trial_joint_out_of_range(campaign_dir):
    _edit(campaign_dir, "joints = [2]", "joints = [3]")
    with pytest.raises(InputError, match="moves joint 3, but the robot has 2 joints"):
        load_campaign(campaign_dir).load_robot()


def test_cli_reports_user_error_without_traceback(campaign_dir, capsys):
    _edit(campaign_dir, "format = 1", "format = 7")
    assert main(["info", str(campaign_dir)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jointlab: error:") and "Traceback" not in err and err.count("\n") == 1


def test_write_manifest_refuses_overwrite(campaign_dir):
    with pytest.raises(FileExistsError):
        write_manifest(campaign_dir / "campaign.toml", {"format": 1})
