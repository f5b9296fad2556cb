"""Issue 29, the read side: inputs that parse but are wrong, ids used as data, links leading out
of the campaign, option values out of range. Each case damages one file of a copy of the demo
campaign (or passes one bad option) and must end with exit status 2, one stderr line naming the
file or the option, and every input byte unchanged."""
from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from ident.cli.main import main
from test_bad_inputs import _digest, _error_lines
from tests_paths import DEMO, set_first_trial_key

TRIAL = "trials/j5-load0-v50-r1"


@pytest.fixture()
def camp(tmp_path):
    dst = tmp_path / "camp"
    shutil.copytree(DEMO, dst)
    return dst


# ---- damage helpers (written from FORMAT.md, sharing nothing with the checks)
def _csv_map(camp, fn, name=TRIAL):
    """Apply ``fn(header, rows) -> (header, rows)`` to a trial log (rows: list of float lists)."""
    p = camp / f"{name}.csv"
    lines = [ln for ln in p.read_text().split("\n") if ln]
    header = lines[0].split(",")
    rows = [[float(c) if c else float("nan") for c in ln.split(",")] for ln in lines[1:]]
    header, rows = fn(header, rows)
    p.write_text("\n".join([",".join(header)] + [",".join("" if np.isnan(v) else repr(v) for v in r)
                                                  for r in rows]) + "\n")
    return p


def _scale_col(col, k):
    def fn(h, rows):
        i = h.index(col)
        for r in rows:
            r[i] *= k
        return h, rows
    return fn


def _swap_names(a, b):
    def fn(h, rows):
        i, j = h.index(a), h.index(b)
        h[i], h[j] = h[j], h[i]
        return h, rows
    return fn


def _const_col(col):
    def fn(h, rows):
        i = h.index(col)
        for r in rows:
            r[i] = rows[0][i]
        return h, rows
    return fn


def _trc_map(camp, fn, name=TRIAL):
    """Apply ``fn(labels, xyz) -> xyz`` to a TRC's coordinates (xyz (T, M, 3) as written)."""
    p = camp / f"{name}.trc"
    lines = p.read_text().split("\n")
    labels = [c for c in lines[3].split("\t")[2:] if c]
    data = [ln.split("\t") for ln in lines[6:] if ln.strip()]
    xyz = np.array([[float(c) if c.strip() else np.nan for c in r[2:2 + 3 * len(labels)]]
                    for r in data]).reshape(len(data), -1, 3)
    xyz = fn(labels, xyz)
    out = lines[:6] + ["\t".join(r[:2] + ["" if np.isnan(v) else f"{v:.5f}" for v in xyz[i].ravel()])
                       for i, r in enumerate(data)]
    p.write_text("\n".join(out) + "\n")
    return p


def _origin(link):
    def fn(labels, xyz):
        for k, lb in enumerate(labels):
            if lb.startswith(link):
                xyz[:, k] = 0.0
        return xyz
    return fn


def _shrink(link):
    def fn(labels, xyz):
        ks = [k for k, lb in enumerate(labels) if lb.startswith(link)]
        c = np.nanmean(xyz[:, ks], axis=1, keepdims=True)
        xyz[:, ks] = c + (xyz[:, ks] - c) / 1000.0        # this link's markers in metres, declared mm
        return xyz
    return fn


def _mirror_links(*links):
    """Mirror the markers of ``links`` through a plane across their centroid, frame by frame."""
    def fn(labels, xyz):
        ks = [k for k, lb in enumerate(labels) if lb.startswith(links)]
        c = np.nanmean(xyz[:, ks, 0], axis=1, keepdims=True)
        xyz[:, ks, 0] = 2 * c - xyz[:, ks, 0]
        return xyz
    return fn


def _mirror(labels, xyz):
    xyz[:, :, 0] *= -1.0
    return xyz


def _drives_tables(camp, fn):
    p = camp / "robot" / "drives.toml"
    text = p.read_text()
    head, *tabs = text.split("[[joint]]")
    tabs = fn(tabs)
    p.write_text(head + "".join("[[joint]]" + t for t in tabs))
    return p


def _swap_tables(tabs):
    tabs[1], tabs[2] = tabs[2], tabs[1]
    if not tabs[1].endswith("\n\n"):
        tabs[1] += "\n"
    return tabs


def _urdf_limits(camp):
    p = camp / "robot" / "arm.urdf"
    text = p.read_text()
    i = text.index('name="joint5"')
    j = text.index("<limit", i)
    k = text.index("/>", j)
    lim = text[j:k]
    import re
    lo = re.search(r'lower="([^"]+)"', lim).group(1)
    up = re.search(r'upper="([^"]+)"', lim).group(1)
    new = lim.replace(f'lower="{lo}"', "LOW").replace(f'upper="{up}"', f'upper="{lo}"').replace("LOW", f'lower="{up}"')
    p.write_text(text[:j] + new + text[k:])
    return p


def _replace(p, old, new):
    t = p.read_text()
    assert old in t
    p.write_text(t.replace(old, new, 1))
    return p


def _second_trial_key(camp, key, value):
    p = camp / "campaign.toml"
    text = p.read_text()
    a = text.index("[[trial]]")
    b = text.index("[[trial]]", a + 1)
    c = text.index("\n" + key + " = ", b)
    d = text.index("\n", c + 1)
    p.write_text(text[:c] + f"\n{key} = {value}" + text[d:])
    return p


def _c3d_rate(camp, factor):
    """The trial's markers as a C3D whose point rate is ``factor`` times the true one."""
    from mocap.io.c3d import write_c3d
    from mocap.io.recording import MarkerRecording
    from mocap.io.trc import read_trc

    rec = read_trc(camp / f"{TRIAL}.trc")
    rate = rec.rate_hz * factor
    t = np.arange(rec.time.size) / rate              # C3D frame numbers start at 1
    p = camp / f"{TRIAL}.c3d"
    write_c3d(p, MarkerRecording(time=t, positions=rec.positions, labels=rec.labels, rate_hz=rate,
                                 units="mm"))
    set_first_trial_key(camp / "campaign.toml", "markers", f'"{TRIAL}.c3d"')
    (camp / f"{TRIAL}.trc").unlink()
    return p


CASES = {
    # ids are data: checked where the manifest is read
    "id leaves the output folder": (lambda c: set_first_trial_key(c / "campaign.toml", "id",
                                                                  '"../../../in/base/trials/x"'),
                                    ["info"], "is not made of letters, digits"),
    "id with a newline": (lambda c: set_first_trial_key(c / "campaign.toml", "id", '"a\\nint x;"'),
                          ["info"], "is not made of letters, digits"),
    "id of 300 characters": (lambda c: set_first_trial_key(c / "campaign.toml", "id", '"' + "a" * 300 + '"'),
                             ["info"], "(300 characters)"),
    "id starting with a dot": (lambda c: set_first_trial_key(c / "campaign.toml", "id", '".hidden"'),
                               ["info"], "not starting with '.'"),
    "ids 1 and \"1\"": (lambda c: (set_first_trial_key(c / "campaign.toml", "id", "1"),
                                   _second_trial_key(c, "id", '"1"'))[0],
                        ["info"], "duplicate trial id '1'"),
    "ids differing only in case": (lambda c: (set_first_trial_key(c / "campaign.toml", "id", '"Run-A"'),
                                              _second_trial_key(c, "id", '"run-a"'))[0],
                                   ["info"], "differ only in case"),
    "two trials share a log": (lambda c: _second_trial_key(c, "log", f'"{TRIAL}.csv"'), ["info"],
                               "read the same log file"),
    # silent-wrong logs
    "log time in milliseconds": (lambda c: _csv_map(c, _scale_col("time", 1000.0)), ["info"],
                                 "time in milliseconds suspected"),
    "torque in mN m": (lambda c: _csv_map(c, _scale_col("tau_5", 1000.0)), ["info"], "mN m suspected"),
    "qm_5 and tau_5 swapped": (lambda c: _csv_map(c, _swap_names("qm_5", "tau_5")), ["info"],
                               "swapped"),
    "moving joint never moves": (lambda c: _csv_map(c, _const_col("qm_5")), ["info"],
                                 "qm_5 never moves"),
    "all rows identical": (lambda c: _csv_map(c, lambda h, rows: (h, [rows[0][:1] and
                                                                      [rows[k][0]] + rows[0][1:]
                                                                      for k in range(len(rows))])),
                           ["info"], "hold the same angles and torques"),
    "one-row log": (lambda c: _csv_map(c, lambda h, rows: (h, rows[:1])), ["info"], "1 sample row"),
    "time of 1e308": (lambda c: _csv_map(c, lambda h, rows: (h, rows[:-1] + [[1e308] + rows[-1][1:]])),
                      ["info"], "jumps by 1e+308 s"),
    # drives and URDF
    "drives tables out of order": (lambda c: _drives_tables(c, _swap_tables), ["info"],
                                   "not in joint order"),
    "drives with 5 joints": (lambda c: _drives_tables(c, lambda t: t[:5]), ["info"],
                             "drives describe 5 joints but the URDF has 6"),
    "drives with 7 joints": (lambda c: _drives_tables(c, lambda t: t + [t[-1].replace('"joint6"', '"joint7"')]),
                             ["info"], "drives describe 7 joints but the URDF has 6"),
    "inverted URDF limits": (_urdf_limits, ["info"], "above upper"),
    "URDF problem on one line": (lambda c: _replace(c / "robot" / "arm.urdf", '<child link="link5"/>',
                                                    '<child link="nolink"/>'), ["info"], ""),
    # markers
    "studied link's markers at the origin": (lambda c: _trc_map(c, _origin("L5")), ["info"],
                                             "rigid fit to the static reference is implausible"),
    "metres declared as mm": (lambda c: _trc_map(c, lambda lb, x: x / 1000.0), ["info"],
                              "metres declared as mm suspected"),
    "one link's markers shrunk": (lambda c: _trc_map(c, _shrink("L5")), ["info"],
                                  "rigid fit to the static reference is implausible"),
    "static trc in metres declared as mm": (lambda c: _trc_map(c, lambda lb, x: x / 1000.0, "static/pose-01"),
                                            ["info"], "metres declared as mm suspected"),
    "moving links' markers mirrored": (lambda c: _trc_map(c, _mirror_links("L5", "L6")),
                                       ["mocap", "--out", "{t}/m"],
                                       "rigid fit to the static reference is implausible"),
    "trc mirrored": (lambda c: _trc_map(c, _mirror), ["mocap", "--out", "{t}/m"],
                     "rigid fit to the static reference is implausible"),
    "c3d point rate changed": (lambda c: _c3d_rate(c, 10.0), ["info"], "the marker rate is wrong"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_parseable_but_wrong_is_refused_in_one_line(case, camp, tmp_path, capsys):
    damage, argv, says = CASES[case]
    path = damage(camp)
    before = _digest(camp)
    argv = [argv[0], str(camp)] + [a.format(t=tmp_path) for a in argv[1:]]
    assert main(argv) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1, err
    assert err[0].startswith(f"jointlab: error: {path}") and says in err[0], err[0]
    assert _digest(camp) == before
    assert not (tmp_path / "m").exists() or not any((tmp_path / "m").rglob("*.csv"))


def test_undamaged_demo_passes_every_check(camp, tmp_path, capsys):
    """The oracle's other half: the same commands on the undamaged copy succeed."""
    assert main(["info", str(camp)]) == 0
    assert main(["mocap", str(camp), "--out", str(tmp_path / "m"), "--trial", "j5-load0-v50-r1"]) == 0


# ---- links leading out of the campaign
def test_marker_link_out_of_the_campaign_is_refused_without_echo(camp, tmp_path, capsys, monkeypatch):
    secret = tmp_path / "secret.trc"
    secret.write_text("TOP-SECRET-CONTENT\nline two\n")
    (camp / f"{TRIAL}.trc").unlink()
    (camp / f"{TRIAL}.trc").symlink_to(secret)
    before = _digest(camp)
    monkeypatch.delenv("JOINTLAB_FOLLOW_LINKS", raising=False)
    assert main(["info", str(camp)]) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and "symbolic link" in err[0] and str(camp / "campaign.toml") in err[0], err
    assert "TOP-SECRET" not in "".join(err)
    assert _digest(camp) == before


def test_link_out_of_the_campaign_is_followed_when_allowed(camp, tmp_path, monkeypatch, capsys):
    outside = tmp_path / "elsewhere.csv"
    shutil.move(camp / f"{TRIAL}.csv", outside)
    (camp / f"{TRIAL}.csv").symlink_to(outside)
    monkeypatch.delenv("JOINTLAB_FOLLOW_LINKS", raising=False)
    assert main(["info", str(camp)]) == 2
    monkeypatch.setenv("JOINTLAB_FOLLOW_LINKS", "1")
    assert main(["info", str(camp)]) == 0


# ---- option values
def _one_line_option(capsys, option):
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and err[0].startswith("jointlab: error:") and option in err[0], err
    return err[0]


@pytest.mark.parametrize("argv,option", [
    (["synth", "{t}/s", "--magnitude", "nan"], "--magnitude"),
    (["synth", "{t}/s", "--log-rate", "1e9"], "--log-rate"),
    (["synth", "{t}/s", "--duration", "inf"], "--duration"),
    (["synth", "{t}/s", "--seed", "-1"], "--seed"),
    (["synth", "{t}/s", "--joints", "5,5"], "--joints"),
    (["synth", "{t}/s", "--loads", "0.01,0.02"], "--loads"),
    (["synth", "{t}/s", "--loads", "0,nan"], "--loads"),
    (["synth", "{t}/s", "--vmax", "inf"], "--vmax"),
    (["design", "--robot", "{c}", "--joint", "5", "--out", "{t}/d", "--seed", "-1"], "--seed"),
    (["diagnose", "{c}", "--out", "{t}/g", "--seed", "-1"], "--seed"),
    (["mocap", "{c}", "--out", "{t}/m", "--min-markers", "0"], "--min-markers"),
    (["calib", "{c}", "--out", "{t}/k", "--min-sweep-deg", "nan"], "--min-sweep-deg"),
    (["design", "--robot", "{c}", "--joint", "5", "--out", "{t}/d", "--dt", "1e-9"], "--dt"),
    (["design", "--robot", "{c}", "--joint", "5", "--out", "{t}/d", "--dt", "0"], "--dt"),
    (["design", "--robot", "{c}", "--joint", "5", "--out", "{t}/d", "--period", "-10"], "--period"),
    (["design", "--robot", "{c}", "--joint", "5", "--out", "{t}/d", "--harmonics", "0"], "--harmonics"),
    (["mocap", "{c}", "--out", "{t}/m", "--reject-sigma", "-1"], "--reject-sigma"),
    (["mocap", "{c}", "--out", "{t}/m", "--trial", "../../../escaped"], "--trial"),
    (["calib", "{c}", "--out", "{t}/k", "--noise-mm", "-1"], "--noise-mm"),
    (["coastdown", "{c}", "--out", "{t}/k", "--joints", "9"], "--joints"),
    (["diagnose", "{c}", "--out", "{t}/g", "--nominal", "stribeck:Vc=-1"], "--nominal"),
])
def test_option_out_of_range_is_one_line(argv, option, camp, tmp_path, capsys):
    before = _digest(camp)
    assert main([a.format(t=tmp_path, c=camp) for a in argv]) == 2
    line = _one_line_option(capsys, option)
    if "1e-9" in argv or "1e9" in argv:
        assert "GiB" in line                              # the estimate is printed
    assert _digest(camp) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camp"]     # nothing written


# ---- calib.json and a damaged recording
@pytest.mark.parametrize("text,says", [
    ("[1, 2, 3]", "T_camera_base"),
    ('{"T_camera_base": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,"x"]]}', "4 rows of 4 numbers"),
    ('{"T_camera_base": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "not a rigid transform"),
    ('{"T_camera_base": [[1,0,0,NaN],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}', "NaN"),
    ("{garbage", "not valid JSON"),
])
def test_bad_calib_json_names_the_file(text, says, camp, tmp_path, capsys):
    cj = tmp_path / "calib.json"
    cj.write_text(text)
    assert main(["mocap", str(camp), "--out", str(tmp_path / "m"), "--calib", str(cj)]) == 2
    line = _one_line_option(capsys, str(cj))
    assert says in line, line


def test_damaged_rrd_is_refused(tmp_path, capsys):
    from mocap.io.plausibility import check_rrd

    good = tmp_path / "a.rrd"
    import rerun as rr

    rec = rr.RecordingStream("jointlab-test")
    rec.save(str(good))
    for k in range(50):
        rec.log("x", rr.Scalars(float(k)) if hasattr(rr, "Scalars") else rr.Scalar(float(k)))
    rec.flush()
    rec.disconnect()
    check_rrd(good)                                       # an intact recording passes
    raw = good.read_bytes()
    bad = tmp_path / "b.rrd"
    bad.write_bytes(raw[: len(raw) // 2 + 7])
    assert main(["view", str(bad)]) == 2
    _one_line_option(capsys, str(bad))
    (tmp_path / "c.rrd").write_bytes(b"not a recording at all")
    assert main(["view", str(tmp_path / "c.rrd")]) == 2
    _one_line_option(capsys, "c.rrd")


# ---- coast-down without a torque cut (the check on a log written here)
def _coast_log(cut: bool):
    from mocap.io.robotlog import RobotLog

    t = np.arange(0.0, 6.0, 0.005)
    rng = np.random.default_rng(3)
    tau = np.where(t < 2.0, 8.0, 0.0 if cut else 5.0 + 2.0 * np.sin(3 * t)) + 0.02 * rng.standard_normal(t.size)
    q = np.cumsum(np.where(t < 4.0, 1.0, 0.0)) * 0.005
    return RobotLog(time=t, qm=q[:, None], tau=tau[:, None])


def test_coastdown_without_a_torque_cut_is_refused():
    from types import SimpleNamespace

    from mocap.io.errors import InputError
    from mocap.io.plausibility import check_log

    rec = SimpleNamespace(joints=(1,), vmax_frac=1.0, kind="coastdown")
    check_log(_coast_log(cut=True), rec, None, "trial")
    with pytest.raises(InputError, match="never cut"):
        check_log(_coast_log(cut=False), rec, None, "trial")


# ---- generated C: a label cannot inject a line
def test_c_labels_cannot_inject_code(tmp_path):
    from ident.friction import CoulombViscous
    from ident.indri.codegen import export_c

    evil = 'j5"; int injected = 1; /* x */\n#error injected\n*/ ??= \\'
    h, c = export_c({evil: CoulombViscous(c=3.0, v=1.5), "plain": CoulombViscous(c=1.0, v=1.0)},
                    tmp_path)
    ref_h, ref_c = export_c({"a": CoulombViscous(c=3.0, v=1.5), "plain": CoulombViscous(c=1.0, v=1.0)},
                            tmp_path / "ref")
    for got, ref in ((h, ref_h), (c, ref_c)):
        assert got.read_text().count("\n") == ref.read_text().count("\n")
        assert "#error" not in got.read_text().replace("#error injected", "") or True
        assert "\n#error" not in got.read_text()
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    so = tmp_path / "lib.so"
    r = subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-shared", "-fPIC", "-o", str(so), str(c), "-lm"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    import ctypes

    L = ctypes.CDLL(str(so))
    L.jl_friction_find.restype = ctypes.c_void_p
    L.jl_friction_find.argtypes = [ctypes.c_char_p]
    assert L.jl_friction_find(evil.encode())                 # the label survives byte for byte


# ---- a malformed --angles folder
def _angles(tmp_path, name, text):
    d = tmp_path / "angles"
    d.mkdir(exist_ok=True)
    if name is not None:
        (d / name).write_bytes(text if isinstance(text, bytes) else text.encode())
    return d


_T = "\n".join(f"{1305.4 + 0.01 * k:.3f},{0.3 + 0.001 * k:.4f},0.8,12" for k in range(50))


@pytest.mark.parametrize("name,text,names_file,says", [
    (None, "", False, "holds no <trial id>.csv"),
    ("j5-load0-v50-r1.csv", "time,q_5,rms_mm,n_markers\n" + _T.replace(",0.3", ",57.3"), True,
     "degrees suspected"),
    ("j5-load0-v50-r1.csv", b"time,q_5\n1.0,\xff\n", True, "is not utf-8"),
    ("j5-load0-v50-r1.csv", "time,q_4,rms_mm,n_markers\n" + _T, True, "no q_5 column"),
    ("j5-load0-v50-r1.csv", "time,q_5,rms_mm,n_markers\n1.0,abc,0,1\n", True, "not a number"),
])
def test_malformed_angles_folder_is_one_line(name, text, names_file, says, camp, tmp_path, capsys):
    d = _angles(tmp_path, name, text)
    before = _digest(camp)
    assert main(["diagnose", str(camp), "--out", str(tmp_path / "g"), "--angles", str(d)]) == 2
    line = _one_line_option(capsys, str(d / name) if names_file else str(d))
    assert says in line, line
    assert _digest(camp) == before and not (tmp_path / "g").exists()


def test_angles_argument_that_is_a_file(camp, tmp_path, capsys):
    f = tmp_path / "angles.csv"
    f.write_text("time,q_5\n")
    assert main(["diagnose", str(camp), "--out", str(tmp_path / "g"), "--angles", str(f)]) == 2
    assert "must be a folder" in _one_line_option(capsys, str(f))


# ---- URDF problems: one line naming the URDF, never the C++ parser's own lines
_URDF_DAMAGE = {
    "missing child link": (lambda t: t.replace('<child link="link5"/>', '<child link="nolink"/>', 1),
                           "is not a link of the URDF"),
    "non-numeric origin": (lambda t: t.replace('<origin xyz="0 0 0.2"', '<origin xyz="0 0 abc"', 1),
                           "is not 3 finite numbers"),
    "truncated": (lambda t: t[: len(t) // 2], "not valid XML"),
    "two roots": (lambda t: t.replace("</robot>", '<link name="orphan"/></robot>'), "2 root links"),
    "repeated joint name": (lambda t: t.replace('name="joint2"', 'name="joint1"', 1), "is repeated"),
    "nan limit": (lambda t: t.replace('upper="3.0892327760299634"', 'upper="nan"', 1), "finite"),
    "negative mass": (lambda t: __import__("re").sub(r'<mass value="[^"]*"', '<mass value="-3"', t, count=1),
                      "negative mass"),
}


@pytest.mark.parametrize("case", list(_URDF_DAMAGE))
def test_urdf_problem_is_one_line(case, camp, capfd):
    fn, says = _URDF_DAMAGE[case]
    p = camp / "robot" / "arm.urdf"
    text = p.read_text()
    assert fn(text) != text
    p.write_text(fn(text))
    before = _digest(camp)
    assert main(["info", str(camp)]) == 2
    err = _error_lines(capfd.readouterr().err)           # file descriptor 2, C++ output included
    assert len(err) == 1 and err[0].startswith(f"jointlab: error: {p}") and says in err[0], err
    assert _digest(camp) == before


def test_coastdown_command_refuses_a_trial_without_a_torque_cut(tmp_path, capsys):
    """The coast-down world of tests/coastdown_world.py with the drive torque kept on after
    each cut (the logged torque held at its last driven value): exit 2 naming the log."""
    from coastdown_world import write_campaign

    root = tmp_path / "camp"
    write_campaign(root, 3, f_log=200.0)
    log = next((root / "trials").glob("*.csv"))
    lines = log.read_text().split("\n")
    head = lines[0].split(",")
    k = head.index("tau_1")
    cells = [ln.split(",") for ln in lines[1:] if ln]
    tau = np.array([float(c[k]) if c[k] else np.nan for c in cells])
    big = 0.3 * np.nanmax(np.abs(tau))
    held = tau.copy()
    for i in range(1, held.size):                      # below 30 % of the peak: hold the last
        if not abs(held[i]) >= big:                    # driven value (the drive never lets go)
            held[i] = held[i - 1]
    for c, v in zip(cells, held):
        c[k] = repr(float(v))
    lines = [lines[0]] + [",".join(c) for c in cells]
    log.write_text("\n".join(lines))
    before = _digest(root)
    assert main(["coastdown", str(root), "--out", str(tmp_path / "out")]) == 2
    err = _error_lines(capsys.readouterr().err)
    assert len(err) == 1 and str(log) in err[0] and "never cut" in err[0], err
    assert _digest(root) == before and not (tmp_path / "out").exists()
