"""Seeded fuzzing of the input readers (issue 17): mutated robot logs, TRC files, manifests and
C3D files end in one of the documented outcomes only:

* a parsed result whose numbers equal an independent parse of the mutated text (the parsers
  here follow FORMAT.md and share no code with the readers), so no column or coordinate is ever
  shifted silently; or
* an :class:`InputError` of one line that names the file.

Any other exception fails the test. The fast variants run a few thousand mutations in well under
a minute; ``-m slow`` runs five times as many seeds.
"""
from __future__ import annotations

import math
import re
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest

from mocap.io.campaign import load_campaign
from mocap.io.errors import InputError, InputWarning
from mocap.io.robotlog import read_robot_log
from mocap.io.trc import read_trc
from tests_paths import DEMO


# ---------------------------------------------------------------------------------------------
# mutations (bytes in, bytes out; every choice from the seeded generator)
HUGE = (b"1e308", b"-1e308", b"inf", b"-inf", b"1e400", b"nan", b"1e30", b"-9e99")
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _mutate(data: bytes, rng: np.random.Generator, seps: bytes) -> tuple[str, bytes]:
    kind = ("flip", "del_sep", "dbl_sep", "truncate", "dup_line", "del_line", "non_utf8",
            "huge", "flip2")[rng.integers(9)]
    n = len(data)
    if kind in ("flip", "flip2"):
        out = bytearray(data)
        for _ in range(1 if kind == "flip" else 2):
            out[rng.integers(n)] = rng.integers(256)
        return kind, bytes(out)
    if kind in ("del_sep", "dbl_sep"):
        pos = [i for i, b in enumerate(data) if b in seps]
        i = pos[rng.integers(len(pos))]
        return kind, data[:i] + data[i + 1:] if kind == "del_sep" else data[:i + 1] + data[i:]
    if kind == "truncate":
        return kind, data[:rng.integers(n)]
    if kind in ("dup_line", "del_line"):
        lines = data.split(b"\n")
        i = int(rng.integers(len(lines)))
        lines[i:i + 1] = [lines[i]] * (2 if kind == "dup_line" else 0)
        return kind, b"\n".join(lines)
    if kind == "non_utf8":
        i = rng.integers(n)
        return kind, data[:i] + (b"\xff", b"\xe9", b"\xc3\x28", b"\x80")[rng.integers(4)] + data[i:]
    nums = list(NUMBER.finditer(data))
    m = nums[rng.integers(len(nums))]
    return kind, data[:m.start()] + HUGE[rng.integers(len(HUGE))] + data[m.end():]


def _one_line_naming(exc: InputError, path: Path) -> None:
    msg = str(exc)
    assert "\n" not in msg and "\r" not in msg, msg
    assert str(path) in msg, msg


def _same(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))
                                              | np.isclose(a, b, rtol=1e-15, atol=0)))


# ---------------------------------------------------------------------------------------------
# robot log CSV
def _csv_base() -> bytes:
    rng = np.random.default_rng(0)
    rows = ["time,qm_1,qm_2,tau_1,tau_2,qd_1,temp_1"]
    for k in range(14):
        cells = [f"{100 + 0.005 * k:.3f}"] + [f"{v:.4f}" for v in rng.normal(size=6)]
        if k in (3, 9):
            cells[2 + (k == 9)] = ""           # missing samples are empty cells
        rows.append(",".join(cells))
    return ("\n".join(rows) + "\n").encode()


_FORMAT_NAME = re.compile(r"^(time|(qm|tau|qd)_[1-9][0-9]*)$")


def _csv_oracle(text: str) -> dict | None:
    """FORMAT.md's robot log, parsed here: name -> column, or None where the text is not a
    valid log (or has no samples)."""
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in text.split("\n")]
    header = [h.strip() for h in lines[0].split(",")]
    rows = [ln.split(",") for ln in lines[1:] if ln.strip()]
    if not rows or any(len(r) != len(header) for r in rows) or len(set(header)) != len(header):
        return None
    cols = {h: [] for h in header}
    for r in rows:
        for h, c in zip(header, r):
            c = c.strip()
            try:
                cols[h].append(math.nan if c == "" or c.lower() == "nan" else float(c))
            except ValueError:
                return None
    return cols


def _read(reader, path: Path):
    """The reader's result, or None after checking its InputError is one line naming ``path``."""
    try:
        return reader(path)
    except InputError as exc:
        _one_line_naming(exc, path)
        return None


def _checker(reader, compare):
    """check(path, raw) -> "read" or "error": the reader's InputError is one line naming the
    file, and what it reads equals ``compare``'s independent parse of ``raw``."""
    def check(path: Path, raw: bytes) -> str:
        res = _read(reader, path)
        if res is None:
            return "error"
        compare(res, raw)
        return "read"
    return check


def _compare_csv(log, raw: bytes) -> None:
    text = raw.decode("utf-8-sig") if _utf8(raw) else ""
    cols = _csv_oracle(text)
    assert cols is not None, f"read a log the independent parse finds invalid:\n{text}"
    got = {"time": log.time}
    got.update({f"qm_{j + 1}": log.qm[:, j] for j in range(log.n_joints)})
    got.update({f"tau_{j + 1}": log.tau[:, j] for j in range(log.n_joints)})
    got.update(log.extra)
    for h, v in cols.items():
        assert h in got and _same(got[h], v), f"column {h!r} differs:\n{text}"
    assert set(log.extra) <= set(cols)
    base = [h for h in _csv_base().decode().split("\n", 1)[0].split(",")]
    now = list(cols)
    if len(now) == len(base):   # a FORMAT.md name damaged into an extra column loses its joint
        for b, h in zip(base, now):
            assert h == b or not _FORMAT_NAME.match(b) or _FORMAT_NAME.match(h), \
                f"column {b!r} renamed {h!r} was read as an extra column:\n{text}"
    for j in range(log.n_joints):  # joints without a column are all NaN, never filled
        for sym, X in (("qm", log.qm), ("tau", log.tau)):
            if f"{sym}_{j + 1}" not in cols:
                assert np.all(np.isnan(X[:, j]))


# ---------------------------------------------------------------------------------------------
# TRC
_TRC_LABELS = ("A", "B", "C", "D")


def _trc_base() -> bytes:
    rng = np.random.default_rng(1)
    M = len(_TRC_LABELS)
    head = ["PathFileType\t4\t(X/Y/Z)\tfuzz.trc",
            "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
            f"100\t100\t12\t{M}\tmm\t100\t1\t12",
            "Frame#\tTime\t" + "\t\t\t".join(_TRC_LABELS) + "\t\t",
            "\t\t" + "\t".join(f"{a}{k}" for k in range(1, M + 1) for a in "XYZ"), ""]
    rows = []
    for f in range(12):
        xyz = [f"{v:.3f}" for v in rng.normal(500.0, 200.0, size=3 * M)]
        if f in (4, 7):
            m = M - 1 if f == 4 else 1                 # occluded: three empty cells
            xyz[3 * m:3 * m + 3] = ["", "", ""]
        rows.append("\t".join([str(f + 1), f"{f / 100:.2f}"] + xyz))
    return ("\n".join(head + rows) + "\n").encode()


def _trc_oracle(raw: bytes):
    """(time, positions in m) from the TRC layout in FORMAT.md, or None where it is invalid."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if len(lines) < 5:
        return None
    sep = "\t" if "\t" in lines[1] else ","
    keys = [c.strip() for c in lines[1].split(sep)]
    vals = [c.strip() for c in lines[2].split(sep)]
    hdr = dict(zip(keys, vals))
    scale = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "millimeters": 1e-3, "meters": 1.0}.get(
        hdr.get("Units", "").lower())
    if scale is None:
        return None
    labels = [c.strip() for c in lines[3].split(sep)[2:] if c.strip()]
    M = len(labels)
    start = 4
    coord = [c.strip() for c in lines[4].split(sep)[2:] if c.strip()]
    if coord and re.fullmatch(r"[XYZ]\d+", coord[0], re.IGNORECASE):
        start = 5
    t, P = [], []
    for ln in lines[start:]:
        cells = ln.split(sep)
        if not "".join(cells).strip():
            continue
        if len(cells) < 2 + 3 * M or any(c.strip() not in ("", "nan", "NaN") for c in cells[2 + 3 * M:]):
            return None
        try:
            v = [math.nan if c.strip() == "" else float(c) for c in cells[1:2 + 3 * M]]
        except ValueError:
            return None
        xyz = np.array(v[1:]).reshape(M, 3)
        xyz[~np.all(np.isfinite(xyz), axis=1)] = np.nan
        t.append(v[0])
        P.append(xyz * scale)
    return labels, np.array(t), np.array(P).reshape(len(t), M, 3)


def _compare_trc(rec, raw: bytes) -> None:
    ref = _trc_oracle(raw)
    assert ref is not None, f"read a TRC the independent parse finds invalid:\n{raw!r}"
    labels, t, P = ref
    assert list(rec.labels) == labels
    assert _same(rec.time, t), f"time differs:\n{raw!r}"
    assert _same(rec.positions, P), f"coordinates differ (shifted?):\n{raw!r}"


# ---------------------------------------------------------------------------------------------
# campaign.toml (paths are not opened: check_files=False)
def _compare_toml(camp, raw: bytes) -> None:
    path = camp.manifest
    doc = tomllib.loads(raw.decode("utf-8"))
    assert doc["format"] == 1
    assert camp.urdf == path.parent / doc["robot"]["urdf"]
    assert {k: tuple(v) for k, v in doc.get("markers", {}).items()} == camp.markers
    tabs = doc.get("trial", [])
    assert [str(t["id"]) for t in tabs] == [t.id for t in camp.trials]
    for tab, tr in zip(tabs, camp.trials):
        assert tuple(tab["joints"]) == tr.joints
        assert tr.load_kg == tab.get("load_kg", 0.0) and tr.vmax_frac == tab.get("vmax_frac", 1.0)
        assert tr.log == path.parent / tab["log"]
        assert tr.extra.get("time_offset") == tab.get("time_offset")
    assert [c.joint for c in camp.calib] == [c["joint"] for c in doc.get("calib", [])]


_check_csv = _checker(read_robot_log, _compare_csv)
_check_trc = _checker(read_trc, _compare_trc)
_check_toml = _checker(lambda p: load_campaign(p, check_files=False), _compare_toml)


# ---------------------------------------------------------------------------------------------
def _run(name: str, seed: int, n: int, tmp_path: Path, base: bytes, seps: bytes, check) -> dict:
    rng = np.random.default_rng([seed, sum(name.encode())])
    path = tmp_path / name
    outcomes = {"read": 0, "error": 0}
    for _ in range(n):
        kind, raw = _mutate(base, rng, seps)
        path.write_bytes(raw)
        try:
            outcomes[check(path, raw)] += 1
        except AssertionError as exc:
            raise AssertionError(f"seed {seed}, mutation {kind}: {exc}") from None
    return outcomes


def _utf8(raw: bytes) -> bool:
    try:
        raw.decode("utf-8-sig")
        return True
    except UnicodeDecodeError:
        return False


def _all(seed: int, tmp_path: Path, scale: int = 1) -> dict:
    toml_base = (DEMO / "campaign.toml").read_bytes()
    return {"csv": _run("log.csv", seed, 400 * scale, tmp_path, _csv_base(), b",\n", _check_csv),
            "trc": _run("m.trc", seed, 400 * scale, tmp_path, _trc_base(), b"\t\n", _check_trc),
            "toml": _run("campaign.toml", seed, 250 * scale, tmp_path, toml_base, b'=",[]\n',
                         _check_toml)}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fuzzed_text_inputs_parse_correctly_or_fail_in_one_line(seed, tmp_path):
    out = _all(seed, tmp_path)
    # the mutations must exercise both outcomes, or the test could not fail
    for kind, o in out.items():
        assert o["read"] >= 20 and o["error"] >= 50, (kind, o)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3, 8))
def test_fuzzed_text_inputs_long(seed, tmp_path):
    _all(seed, tmp_path, scale=3)


def test_unmutated_bases_read_back_exactly(tmp_path):
    """The oracles agree with the readers on the untouched files (and the files are valid)."""
    p = tmp_path / "log.csv"
    p.write_bytes(_csv_base())
    assert _check_csv(p, _csv_base()) == "read"
    p = tmp_path / "m.trc"
    p.write_bytes(_trc_base())
    assert _check_trc(p, _trc_base()) == "read"
    p = tmp_path / "campaign.toml"
    p.write_bytes((DEMO / "campaign.toml").read_bytes())
    assert _check_toml(p, p.read_bytes()) == "read"


# ---------------------------------------------------------------------------------------------
# C3D: ezc3d reads in a subprocess (a damaged file may crash it), so fewer mutations
def _c3d_base(tmp_path: Path) -> tuple[bytes, np.ndarray]:
    from mocap.io.c3d import write_c3d
    from mocap.io.recording import MarkerRecording

    rng = np.random.default_rng(2)
    T, M = 30, 3
    P = rng.normal(0.5, 0.2, size=(T, M, 3))
    P[5, 1] = np.nan
    rec = MarkerRecording(time=np.arange(T) / 100.0, positions=P, labels=("A", "B", "C"), rate_hz=100.0)
    p = write_c3d(tmp_path / "base.c3d", rec)
    return p.read_bytes(), P


def _check_c3d(path: Path, raw: bytes, base: bytes, P: np.ndarray) -> str:
    from mocap.io.markers import read_markers

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", InputWarning)
        try:
            rec = read_markers(path)
        except InputError as exc:
            _one_line_naming(exc, path)
            return "error"
    told = [w for w in caught if issubclass(w.category, InputWarning)]
    assert all(str(path) in str(w.message) for w in told)
    X = rec.positions
    assert X.ndim == 3 and X.shape[2] == 3 and rec.n_frames >= 1
    assert np.all(np.isnan(X) | (np.abs(X) <= 1e4)), "absurd coordinates passed"
    assert np.all(np.diff(rec.time) > 0)
    if len(raw) < len(base) and rec.n_frames < P.shape[0]:
        assert told, "a truncated file read as a shorter recording without a warning"
    if raw[512:] == base[512:] and raw[:512] == base[:512]:
        assert _same(X, P)
    return "read"


def test_fuzzed_c3d_parses_or_fails_in_one_line(tmp_path):
    pytest.importorskip("ezc3d")
    base, P = _c3d_base(tmp_path)
    rng = np.random.default_rng(7)
    path = tmp_path / "m.c3d"
    outcomes = {"read": 0, "error": 0}
    for k in range(40):
        if k % 4 == 0:
            raw = base[:int(rng.integers(512, len(base)))]           # truncation
        else:
            out = bytearray(base)
            for _ in range(1 + k % 3):
                out[rng.integers(len(base))] = rng.integers(256)   # byte flips
            raw = bytes(out)
        path.write_bytes(raw)
        outcomes[_check_c3d(path, raw, base, P)] += 1
    assert outcomes["read"] >= 5 and outcomes["error"] >= 5, outcomes


# ---------------------------------------------------------------------------------------------
# parseable but wrong (issue 29): mutations that keep every file readable but change its meaning.
# The oracle is the mutation itself: a unit change (x1000), a column swap or a mirrored marker
# file must be refused with one line naming the file; a benign change of the same size class
# (a clock shift of both streams, a torque scaled within 25 %, 0.3 mm marker jitter) must pass.
WRONG = ("time_ms", "torque_mNm", "swap_q_tau", "mirror_x", "metres_as_mm")
BENIGN = ("clock_shift", "torque_scale", "marker_jitter")


def _edit_csv(path: Path, fn) -> None:
    lines = [ln for ln in path.read_text().split("\n") if ln]
    head = lines[0].split(",")
    rows = np.array([[float(c) if c else np.nan for c in ln.split(",")] for ln in lines[1:]])
    head, rows = fn(head, rows)
    path.write_text("\n".join([",".join(head)] + [",".join("" if np.isnan(v) else repr(float(v)) for v in r)
                                                  for r in rows]) + "\n")


def _edit_trc(path: Path, fn) -> None:
    lines = path.read_text().split("\n")
    data = [ln.split("\t") for ln in lines[6:] if ln.strip()]
    n = max(len(r) for r in data)
    X = np.array([[float(c) if c.strip() else np.nan for c in r[1:]] + [np.nan] * (n - len(r))
                  for r in data])             # time, then x y z per marker
    X = fn(X)
    out = lines[:6] + ["\t".join([r[0]] + ["" if np.isnan(v) else f"{v:.6f}" for v in X[i]])
                       for i, r in enumerate(data)]
    path.write_text("\n".join(out) + "\n")


def _parseable_mutation(kind: str, camp: Path, trial: str, rng) -> None:
    csv, trc = camp / f"trials/{trial}.csv", camp / f"trials/{trial}.trc"
    if kind == "time_ms":
        _edit_csv(csv, lambda h, r: (h, np.column_stack([r[:, :1] * 1000.0, r[:, 1:]])))
    elif kind == "torque_mNm":
        def fn(h, r):
            r = r.copy()
            r[:, h.index("tau_5")] *= 1000.0
            return h, r
        _edit_csv(csv, fn)
    elif kind == "swap_q_tau":
        def fn(h, r):
            h = list(h)
            i, j = h.index("qm_5"), h.index("tau_5")
            h[i], h[j] = h[j], h[i]
            return h, r
        _edit_csv(csv, fn)
    elif kind == "mirror_x":
        def fn(X):
            X = X.copy()
            X[:, 1::3] *= -1.0
            return X
        _edit_trc(trc, fn)
    elif kind == "metres_as_mm":
        _edit_trc(trc, lambda X: np.column_stack([X[:, :1], X[:, 1:] / 1000.0]))
    elif kind == "clock_shift":
        s = float(rng.uniform(-100.0, 100.0))
        _edit_csv(csv, lambda h, r: (h, np.column_stack([r[:, :1] + s, r[:, 1:]])))
        _edit_trc(trc, lambda X: np.column_stack([X[:, :1] + s, X[:, 1:]]))
    elif kind == "torque_scale":
        k = float(rng.uniform(0.8, 1.25))

        def fn(h, r):
            r = r.copy()
            r[:, h.index("tau_5")] *= k
            return h, r
        _edit_csv(csv, fn)
    elif kind == "marker_jitter":
        _edit_trc(trc, lambda X: np.column_stack([X[:, :1], X[:, 1:] + 0.3 * rng.standard_normal(X[:, 1:].shape)]))


@pytest.fixture(scope="module")
def demo_refs(tmp_path_factory):
    """The demo's static references (camera pose and marker positions in link frames), once."""
    from ident.study.angles import campaign_references

    camp = load_campaign(DEMO)
    robot = camp.load_robot()
    refs, _ = campaign_references(camp, robot, None)
    return robot, refs


@pytest.mark.parametrize("seed", [0, 1])
def test_parseable_but_wrong_inputs_are_refused(seed, tmp_path, demo_refs):
    import shutil

    from mocap.io.plausibility import check_trial_rigid_fit

    robot, refs = demo_refs
    rng = np.random.default_rng(100 + seed)
    trials = [t.id for t in load_campaign(DEMO).trials]
    kinds = list(WRONG + BENIGN)
    for k in range(8):
        kind = kinds[(seed * 8 + k) % len(kinds)]
        trial = trials[int(rng.integers(len(trials)))]
        camp = tmp_path / f"c{k}"
        shutil.copytree(DEMO, camp)
        _parseable_mutation(kind, camp, trial, rng)
        c = load_campaign(camp)
        tr = c.trial(trial)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", InputWarning)
                log = c.read_log(tr, robot)
                m = c.read_markers(tr, robot)
                check_trial_rigid_fit(m, log, refs, robot, tr)
        except InputError as exc:
            assert kind in WRONG, f"{kind} on {trial} refused: {exc}"
            where = camp / f"trials/{trial}.{'trc' if kind in ('mirror_x', 'metres_as_mm') else 'csv'}"
            _one_line_naming(exc, where)
        else:
            assert kind in BENIGN, f"{kind} on {trial} passed"
