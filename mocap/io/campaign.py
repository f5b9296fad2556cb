"""The campaign manifest (FORMAT.md, ``campaign.toml``) and its validation."""
from __future__ import annotations

import dataclasses
import functools
import math
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from mocap.io.errors import InputError, quiet_stderr, read_text
from mocap.io.ids import TRIAL_ID, check_trial_id  # noqa: F401  (re-exported)
from mocap.io.markers import read_markers
from mocap.io.ranges import check_range
from mocap.io.plausibility import (check_drives_count, check_drives_order, check_log,
                                   check_marker_shapes, check_marker_time, check_marker_timing)
from mocap.io.robotlog import read_robot_log
from mocap.quality import check_marker_extent, check_marker_units
from mocap.robot import Robot
from mocap.urdf import check_urdf, check_urdf_limits

TRIAL_KINDS = ("excitation", "coastdown", "reversals", "constant_velocity")

#: environment variable that lets a campaign's inputs be symbolic links leading out of it
FOLLOW_LINKS_ENV = "JOINTLAB_FOLLOW_LINKS"


def links_allowed() -> bool:
    """True when the user allows inputs reached through symbolic links that leave the campaign
    folder (``JOINTLAB_FOLLOW_LINKS=1``; docs/inputs.md)."""
    return os.environ.get(FOLLOW_LINKS_ENV, "").strip().lower() not in ("", "0", "no", "false", "off")


@dataclass(frozen=True)
class Recording:
    """A marker file plus the robot log of the same interval (``markers`` is None for a trial
    of a campaign without motion capture)."""

    markers: Path | None
    log: Path


@dataclass(frozen=True)
class CalibSweep(Recording):
    joint: int = 1


@dataclass(frozen=True)
class Trial(Recording):
    """One ``[[trial]]`` of a campaign: a recording of some joints moving, with its conditions.

    A marker file and the robot log of the same interval [1]_; the conditions (load, speed,
    repetition) are the factors of the thesis's tables [2]_.

    Attributes
    ----------
    markers : pathlib.Path or None
        The marker file (None: a campaign without motion capture).
    log : pathlib.Path
        The robot log.
    id : str
        The trial's id, unique in the manifest.
    joints : tuple of int
        The moving joints, 1-based; the others are braked.
    load_kg : float
        Extra end-effector mass (kg).
    vmax_frac : float
        Peak speed as a fraction of the joints' maximum speed.
    repetition : int
        Repetition number of the same conditions.
    kind : str
        ``"excitation"`` (default), ``"coastdown"``, ``"reversals"`` or
        ``"constant_velocity"``.
    note : str
        Free text.
    extra : dict
        Other keys of the table (e.g. ``time_offset``, s).
    unlogged_torque : tuple of int
        Moving joints whose torque was not logged.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    .. [2] PA10 thesis (seeds 002), Tables 5-1 to 5-3.
    """

    id: str = ""
    joints: tuple[int, ...] = ()
    load_kg: float = 0.0
    vmax_frac: float = 1.0
    repetition: int = 1
    kind: str = "excitation"
    note: str = ""
    extra: dict = field(default_factory=dict)
    unlogged_torque: tuple[int, ...] = ()   # moving joints whose torque was not logged


@dataclass(frozen=True)
class Campaign:
    """A loaded ``campaign.toml``: the robot, the marker sets and every recording, validated.

    What :func:`load_campaign` returns [1]_; the recordings are read through it
    (:meth:`read_log`, :meth:`read_markers`), so that the ``[robot] coupling`` and the
    plausibility checks apply to every command.

    Attributes
    ----------
    root : pathlib.Path
        The campaign folder.
    name : str
        The campaign's name.
    urdf : pathlib.Path
        The robot's URDF.
    drives : pathlib.Path or None
        ``robot/drives.toml`` (None: drives from the URDF limits).
    gravity : tuple of float
        Gravity in the base link's frame (m/s^2).
    markers : dict
        Link name -> tuple of marker labels (empty: no motion capture).
    static : tuple of Recording
        The ``[[static]]`` recordings (static poses, thesis eq. 3-4 [2]_).
    calib : tuple of CalibSweep
        The camera-to-base calibration sweeps.
    trials : tuple of Trial
        The trials, in manifest order.
    extra : dict
        Other keys of the manifest.
    coupling : tuple or None
        ``[robot] coupling`` rows: ``q_urdf = coupling @ q_log``.
    base_link, tip_link : str or None
        ``[robot]`` ends of the arm's chain.
    fixed : dict
        ``[robot] fixed``: joint name -> value of the joints off the chain.
    mjcf : pathlib.Path or None
        ``[robot] mjcf``: the user's MuJoCo model of the arm (None: none declared).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    .. [2] PA10 thesis (seeds 002), eq. 3-4.
    """

    root: Path
    name: str
    urdf: Path
    drives: Path
    gravity: tuple[float, float, float]
    markers: dict  # link name -> tuple of labels
    static: tuple[Recording, ...]
    calib: tuple[CalibSweep, ...]
    trials: tuple[Trial, ...]
    extra: dict = field(default_factory=dict)
    coupling: tuple | None = None  # [robot] coupling rows: q_urdf = coupling @ q_log
    base_link: str | None = None   # [robot] base_link, tip_link, fixed: which chain is the arm
    tip_link: str | None = None
    fixed: dict = field(default_factory=dict)
    mjcf: Path | None = None       # [robot] mjcf: the user's MuJoCo model of the arm (FORMAT.md)

    @property
    def has_markers(self) -> bool:
        """False for a campaign without motion capture (no ``[markers]`` table)."""
        return bool(self.markers)

    @property
    def manifest(self) -> Path:
        return self.root / "campaign.toml"

    def trial(self, trial_id: str) -> Trial:
        check_trial_id(trial_id, "trial", path=self.manifest)
        for t in self.trials:
            if t.id == trial_id:
                return t
        raise InputError(f"no trial {trial_id!r} in the campaign", path=self.manifest)

    def link_of_label(self) -> dict:
        return {lb: link for link, labels in self.markers.items() for lb in labels}

    def load_robot(self):
        """Load and check the campaign's robot (URDF, drives, chain).

        :meth:`mocap.robot.Robot.from_urdf` after :func:`mocap.urdf.check_urdf`, then the
        manifest checked against it: marked links, trial joints, coupling rows, calibration
        sweeps [1]_.

        Returns
        -------
        mocap.robot.Robot
            The arm.

        Raises
        ------
        InputError
            If the URDF or drives file is invalid, or the manifest names a link or joint the
            robot lacks.

        References
        ----------
        .. [1] jointlab data format (docs/format.md), sec. campaign.toml, robot/drives.toml.
        """

        check_urdf(self.urdf)                  # one line, before a C++ parser prints its own
        chain = dict(base_link=self.base_link, tip_link=self.tip_link, fixed=self.fixed, where=self.manifest)
        with quiet_stderr():
            bare = Robot.from_urdf(self.urdf, None, self.gravity, **chain)
        check_urdf_limits(bare, self.urdf)
        if self.drives is not None:
            check_drives_count(self.drives, bare.n)
        with quiet_stderr():
            robot = Robot.from_urdf(self.urdf, self.drives, self.gravity, **chain)
        if self.drives is not None:
            check_drives_order(robot, self.drives)
        missing = [lk for lk in self.markers if lk not in robot.chain.frames]
        if missing:
            raise InputError(f"[markers] names link {missing[0]!r}, which is not in the URDF "
                             f"(links: {', '.join(robot.link_names)})", path=self.manifest,
                             label=missing[0])
        for t in self.trials:
            bad = [j for j in t.joints if not 1 <= j <= robot.n]
            if bad:
                raise InputError(f"trial {t.id!r} moves joint {bad[0]}, but the robot has {robot.n} joints",
                                 path=self.manifest, label=t.id)
            stray = [j for j in t.unlogged_torque if j not in t.joints]
            if stray:
                raise InputError(f"trial {t.id!r}: unlogged_torque names joint {stray[0]}, which is "
                                 f"not in joints = {list(t.joints)}", path=self.manifest,
                                 label="unlogged_torque")
        if self.coupling is not None and len(self.coupling) != robot.n:
            raise InputError(f"[robot] coupling has {len(self.coupling)} rows, the robot has {robot.n} joints",
                             path=self.manifest, label="coupling")
        for c in self.calib:
            if not 1 <= c.joint <= robot.n:
                raise InputError(f"calibration sweep of joint {c.joint}, but the robot has {robot.n} joints",
                                 path=self.manifest)
        return robot

    def read_log(self, rec: Recording, robot=None):
        """Read the robot log of a recording in URDF joints.

        The one place where ``[robot] coupling`` is applied (q, qd and tau) [1]_, and, given
        the ``robot``, where angles far beyond the URDF's limits are refused (degrees
        suspected). Every command reading angles goes through here.

        Parameters
        ----------
        rec : Recording
            A static recording, calibration sweep or trial of this campaign.
        robot : mocap.robot.Robot, optional
            The robot, for the limit checks; None: none.

        Returns
        -------
        mocap.io.robotlog.RobotLog
            The log; a trial's ``unlogged_torque`` columns NaN.

        Raises
        ------
        InputError
            If the log is invalid, implausible, beyond the limits, or lacks a moving joint.

        References
        ----------
        .. [1] jointlab data format (docs/format.md), sec. Coupled joints.
        """

        n = None if robot is None else robot.n
        if n is None and self.coupling is not None:
            n = len(self.coupling)

        log = _take_log(rec.log, n)
        if log is None:
            log = read_robot_log(rec.log, n_joints=n)
        if self.coupling is not None:
            log = log.coupled(self.coupling)
        kind = "trial" if isinstance(rec, Trial) else "calib" if isinstance(rec, CalibSweep) else "static"
        check_log(log, rec, robot, kind)       # units, swaps, no motion (mocap.io.plausibility)
        if robot is not None:
            log.check_limits(robot.lower, robot.upper, robot.joint_names)
            log.check_drive_limits(robot.max_torque, robot.max_velocity, robot.joint_names)
        if isinstance(rec, Trial):
            if rec.unlogged_torque:        # FORMAT.md: their tau_<j> cells are ignored
                import numpy as np

                tau = log.tau.copy()
                tau[:, [j - 1 for j in rec.unlogged_torque if j <= tau.shape[1]]] = np.nan
                log = dataclasses.replace(log, tau=tau)
                for j in rec.unlogged_torque:
                    if j > log.qm.shape[1] or not np.isfinite(log.qm[:, j - 1]).any():
                        raise InputError(f"no qm_{j} values, but trial {rec.id!r} moves joint {j}",
                                         path=log.source, line=1, label=f"qm_{j}")
            try:
                log.check_joints_logged([j for j in rec.joints if j not in rec.unlogged_torque],
                                        what=f"trial {rec.id!r}")
            except InputError as exc:
                if "tau_" in str(exc) and "unlogged_torque" not in str(exc):
                    exc.args = (exc.args[0] + " (a joint whose torque the controller did not log "
                                "belongs in the trial's unlogged_torque = [...])",) + exc.args[1:]
                raise
        return log

    def read_markers(self, rec: Recording, robot=None):
        """The marker file of ``rec`` (:func:`mocap.io.markers.read_markers`, metres); given the
        ``robot``, a cloud of the campaign's markers far larger than the robot reaches is refused
        (units suspected: millimetres declared as metres). Every command reading markers of a
        campaign goes through here."""
        import numpy as np

        m = read_markers(rec.markers)
        check_marker_time(m)
        ours = [k for k, lb in enumerate(m.labels) if lb in self.link_of_label()]
        P = m.positions if len(ours) == len(m.labels) else m.positions[:, ours]   # all ours: no copy
        if robot is not None and ours and np.isfinite(P).any():
            check_marker_units(P, [m.labels[k] for k in ours], robot.chain,
                               path=m.source, check_motion=False)

            check_marker_extent(m, self.link_of_label(), robot.chain)
        if robot is not None and isinstance(rec, Trial):
            self._check_trial_markers(m, rec)
        return m

    def _check_trial_markers(self, m, rec) -> None:
        """A trial's marker file against its log's time span and each link's marker distances
        against the first static recording (:mod:`mocap.io.plausibility`)."""
        log = read_robot_log(rec.log)
        check_marker_timing(m, log)
        _hand_log(rec.log, log)
        if self.static and self.static[0].markers is not None:
            p = self.static[0].markers
            st = p.stat()
            check_marker_shapes(m, _static_markers(str(p), st.st_mtime_ns, st.st_size), self.markers)

    def recordings(self):
        """Every (kind, name, Recording) in the manifest."""
        for k, s in enumerate(self.static, 1):
            yield "static", f"static-{k}", s
        for c in self.calib:
            yield "calib", f"calib-joint-{c.joint}", c
        for t in self.trials:
            yield "trial", t.id, t


#: the logs a trial's marker check read, kept for the :meth:`Campaign.read_log` that follows it
#: (path -> (file identity, log)); each is taken once, at most a few small ones are held
_LOG_HANDOFF: dict = {}
_HANDOFF_MAX_LOGS = 4
_HANDOFF_MAX_BYTES = 16 << 20


def _file_key(path) -> tuple | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _hand_log(path, log) -> None:
    """Keep ``log`` (``read_robot_log(path)``, joints as found) for one :func:`_take_log`."""
    cells = log.time.size * (1 + log.qm.shape[1] + log.tau.shape[1] + len(log.extra))
    key = _file_key(path)
    if key is None or 8 * cells > _HANDOFF_MAX_BYTES:
        return
    _LOG_HANDOFF.pop(str(path), None)
    while len(_LOG_HANDOFF) >= _HANDOFF_MAX_LOGS:
        _LOG_HANDOFF.pop(next(iter(_LOG_HANDOFF)), None)
    _LOG_HANDOFF[str(path)] = (key, log)


def _take_log(path, n_joints: int | None):
    """``read_robot_log(path, n_joints)`` from the log :func:`_hand_log` kept for ``path`` (the
    same file, unchanged), or None: read it. The kept log has the joints the file names; a
    wider robot gets NaN columns, as the reader gives them. Only where the reader's header
    check is the same for both widths (up to 9 joints) and the file names no joint beyond
    ``n_joints`` (that error comes from the reader)."""
    import numpy as np

    got = _LOG_HANDOFF.pop(str(path), None)
    if got is None or got[0] != _file_key(path):
        return None
    log = got[1]
    w = log.qm.shape[1]
    if n_joints is None or n_joints == w:
        return log
    if w > n_joints or n_joints > 9 or log.tau.shape[1] != w:
        return None

    def widen(X):
        out = np.full((X.shape[0], n_joints), np.nan)
        out[:, :w] = X
        return out

    return dataclasses.replace(log, qm=widen(log.qm), tau=widen(log.tau))


@functools.lru_cache(maxsize=4)
def _static_markers(path: str, mtime_ns: int, size: int):
    """A static pose's marker file, read once per version (the reference of every trial's
    marker distances)."""
    return read_markers(path)


def _req(tab: dict, key: str, where: str, path: Path):
    if key not in tab:
        raise InputError(f"{where} has no '{key}'", path=path, label=key)
    return tab[key]


def _num(v, key: str, where: str, path: Path) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{where}: '{key}' must be a number, got {v!r}", path=path, label=key)
    if not math.isfinite(v):
        raise InputError(f"{where}: '{key}' must be a finite number, got {v!r}", path=path, label=key)
    return float(v)


def _check_trial_values(tab: dict, where: str, path: Path) -> None:
    """Physical plausibility of a trial's numbers (FORMAT.md keys, SI; the ranges of
    :data:`mocap.io.ranges.RANGES`)."""
    for key, default in (("load_kg", 0.0), ("vmax_frac", 1.0), ("repetition", 1)):
        check_range("trial", key, tab.get(key, default), path=path, where=where)
    if "time_offset" in tab:
        check_range("trial", "time_offset", tab["time_offset"], path=path, where=where)
    for j in tab.get("joints", []) if isinstance(tab.get("joints"), list) else []:
        check_range("trial", "joints", j, path=path, where=where)
    if "payload_com" in tab and tab["payload_com"] != "unknown":
        com = tab["payload_com"]
        if not (isinstance(com, list) and len(com) == 3):
            raise InputError(f"{where}: payload_com must be [x, y, z] in metres or \"unknown\", got {com!r}",
                             path=path, label="payload_com")
        com = [_num(c, "payload_com", where, path) for c in com]
        if max(abs(c) for c in com) > 5.0:
            raise InputError(f"{where}: payload_com {com!r} is more than 5 m from the flange "
                             "(millimetres written as metres?)", path=path, label="payload_com")


def _inside(root: Path, rel, key: str, where: str, manifest: Path) -> Path:
    """FORMAT.md: paths are relative to the manifest and stay inside the campaign folder."""
    if not isinstance(rel, str) or not rel.strip():
        raise InputError(f"{where}: '{key}' must be a path string", path=manifest, label=key)
    if Path(rel).is_absolute() or rel.startswith(("/", "\\")) or ":" in rel.split("/")[0]:
        raise InputError(f"{where}: {key} path {rel!r} is absolute; paths are relative to the "
                         "campaign folder", path=manifest, label=key)
    p = root / rel
    norm = os.path.normpath(rel.replace("\\", "/"))
    if norm == ".." or norm.startswith("../"):   # lexical: a campaign may link its data in
        raise InputError(f"{where}: {key} path {rel!r} leaves the campaign folder", path=manifest,
                         label=key)
    if not links_allowed():
        real, home = p.resolve(), root.resolve()
        if real != home and home not in real.parents:
            raise InputError(f"{where}: {key} path {rel!r} is reached through a symbolic link that "
                             f"leads out of the campaign folder; set {FOLLOW_LINKS_ENV}=1 to follow it",
                             path=manifest, label=key)
    return p


def _file(root: Path, rel, key: str, where: str, manifest: Path) -> Path:
    p = _inside(root, rel, key, where, manifest)
    if not p.is_file():
        raise InputError(f"{where}: {key} file {rel!r} not found", path=manifest, label=key)
    return p


def load_campaign(path: str | Path, check_files: bool = True) -> Campaign:
    """Read and validate a campaign's ``campaign.toml``.

    The manifest of the data format [1]_: every key, path and trial checked, errors in one
    line naming the file and key.

    Parameters
    ----------
    path : str or pathlib.Path
        The campaign folder or the manifest itself.
    check_files : bool, optional
        Also require every referenced file to exist (default True).

    Returns
    -------
    Campaign
        The validated campaign.

    Raises
    ------
    InputError
        If the manifest is missing, not TOML or of another format, a key is missing or
        invalid, a marker is listed for two links, a path leaves the campaign folder or does
        not exist, or a trial id repeats.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    """
    path = Path(path)
    manifest = path / "campaign.toml" if path.is_dir() else path
    if not manifest.is_file():
        raise InputError("no campaign.toml here", path=manifest)
    root = manifest.parent
    try:
        doc = tomllib.loads(read_text(manifest))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path=manifest) from None
    fmt = doc.get("format")
    if fmt != 1:
        raise InputError(f"unsupported campaign format {fmt!r} (this workbench reads format = 1)",
                         path=manifest, label="format")
    chk = (lambda rel, key, where: _file(root, rel, key, where, manifest)) if check_files else \
        (lambda rel, key, where: _inside(root, rel, key, where, manifest))
    rob = _req(doc, "robot", "the manifest", manifest)
    urdf = chk(_req(rob, "urdf", "[robot]", manifest), "urdf", "[robot]")
    # [robot] drives is optional: without it every joint takes the URDF's limits
    drives = chk(rob["drives"], "drives", "[robot]") if "drives" in rob else None
    mjcf = chk(rob["mjcf"], "mjcf", "[robot]") if "mjcf" in rob else None
    base_link, tip_link = rob.get("base_link"), rob.get("tip_link")
    for key, v in (("base_link", base_link), ("tip_link", tip_link)):
        if v is not None and not (isinstance(v, str) and v.strip()):
            raise InputError(f"[robot] {key} must be a link name, got {v!r}", path=manifest, label=key)
    fixed = rob.get("fixed", {})
    if not isinstance(fixed, dict):
        raise InputError("[robot] fixed must be a table { joint_name = value, ... }", path=manifest,
                         label="fixed")
    grav = rob.get("gravity", [0.0, 0.0, -9.81])
    if not (isinstance(grav, list) and len(grav) == 3):
        raise InputError("[robot] gravity must be a list of 3 numbers", path=manifest, label="gravity")
    grav = tuple(check_range("robot", "gravity", g, path=manifest, where="[robot]") for g in grav)
    for nm, v in fixed.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            check_range("robot", "fixed", v, path=manifest, where=f"[robot] fixed {nm}")
    coupling = _coupling(rob.get("coupling"), manifest)

    markers = {}
    seen = {}
    for link, labels in doc.get("markers", {}).items():
        if not (isinstance(labels, list) and all(isinstance(x, str) for x in labels)):
            raise InputError(f"[markers] {link} must be a list of labels", path=manifest, label=link)
        for lb in labels:
            if lb in seen:
                raise InputError(f"marker {lb!r} is listed for both {seen[lb]!r} and {link!r}",
                                 path=manifest, label=lb)
            seen[lb] = link
        markers[link] = tuple(labels)
    # no [markers] table: a campaign without motion capture (FORMAT.md); the logged angle is
    # the link angle and trials carry no marker files

    static = []
    for k, tab in enumerate(doc.get("static", []), 1):
        w = f"[[static]] number {k}"
        static.append(Recording(chk(_req(tab, "markers", w, manifest), "markers", w),
                                chk(_req(tab, "log", w, manifest), "log", w)))
    calib = []
    for k, tab in enumerate(doc.get("calib", []), 1):
        w = f"[[calib]] number {k}"
        j = _req(tab, "joint", w, manifest)
        if isinstance(j, bool) or not isinstance(j, int):
            raise InputError(f"{w}: 'joint' must be an integer", path=manifest, label="joint")
        calib.append(CalibSweep(chk(_req(tab, "markers", w, manifest), "markers", w),
                                chk(_req(tab, "log", w, manifest), "log", w), joint=j))
    trials = []
    ids = set()
    known = {"id", "joints", "load_kg", "vmax_frac", "repetition", "markers", "log", "kind", "note",
             "unlogged_torque"}
    for k, tab in enumerate(doc.get("trial", []), 1):
        tid = check_trial_id(_req(tab, "id", f"[[trial]] number {k}", manifest),
                             f"[[trial]] number {k}", manifest)
        w = f"trial {tid!r}"
        if tid in ids:
            raise InputError(f"[[trial]] number {k}: duplicate trial id {tid!r} (ids are compared "
                             "as text)", path=manifest, label=tid)
        same = [i for i in ids if i.lower() == tid.lower()]
        if same:   # a tool's file names would collide on a case-insensitive file system
            raise InputError(f"[[trial]] number {k}: trial ids {same[0]!r} and {tid!r} differ only in "
                             "case", path=manifest, label=tid)
        ids.add(tid)
        joints = _req(tab, "joints", w, manifest)
        if not (isinstance(joints, list) and joints and
                all(isinstance(j, int) and not isinstance(j, bool) for j in joints)):
            raise InputError(f"{w}: 'joints' must be a non-empty list of joint numbers",
                             path=manifest, label="joints")
        kind = tab.get("kind", "excitation")
        if kind not in TRIAL_KINDS:
            raise InputError(f"{w}: kind {kind!r} is not one of {', '.join(TRIAL_KINDS)}",
                             path=manifest, label="kind")
        rep = tab.get("repetition", 1)
        if isinstance(rep, bool) or not isinstance(rep, int):
            raise InputError(f"{w}: 'repetition' must be an integer", path=manifest, label="repetition")
        _check_trial_values(tab, w, manifest)
        if "markers" in tab and not markers:
            raise InputError(f"{w} has a marker file but the manifest has no [markers] table "
                             "(which link is each marker glued to?)", path=manifest, label="markers")
        if "markers" not in tab and markers:
            raise InputError(f"{w} has no 'markers' file although the campaign declares [markers]",
                             path=manifest, label="markers")
        trials.append(Trial(
            markers=chk(tab["markers"], "markers", w) if "markers" in tab else None,
            log=chk(_req(tab, "log", w, manifest), "log", w),
            id=str(tid), joints=tuple(joints),
            load_kg=_num(tab.get("load_kg", 0.0), "load_kg", w, manifest),
            vmax_frac=_num(tab.get("vmax_frac", 1.0), "vmax_frac", w, manifest),
            repetition=rep, kind=kind, note=str(tab.get("note", "")),
            extra={kk: vv for kk, vv in tab.items() if kk not in known},
            unlogged_torque=_joint_list(tab.get("unlogged_torque", []), "unlogged_torque", w,
                                        manifest)))
    _refuse_shared_files(trials, manifest)
    top_known = {"format", "name", "robot", "markers", "static", "calib", "trial"}
    return Campaign(root=root, name=str(doc.get("name", root.name)), urdf=urdf, drives=drives,
                    gravity=grav, markers=markers, static=tuple(static), calib=tuple(calib),
                    trials=tuple(trials), extra={k: v for k, v in doc.items() if k not in top_known},
                    coupling=coupling, base_link=base_link, tip_link=tip_link, fixed=dict(fixed),
                    mjcf=mjcf)


def _joint_list(v, key: str, where: str, manifest: Path) -> tuple:
    if not (isinstance(v, list) and all(isinstance(j, int) and not isinstance(j, bool) for j in v)):
        raise InputError(f"{where}: '{key}' must be a list of joint numbers", path=manifest, label=key)
    return tuple(v)


def _refuse_shared_files(trials, manifest: Path) -> None:
    """Two trials reading the same log or marker file (after links are resolved) would pose as
    two repetitions of one recording: refused."""
    owner = {}
    for t in trials:
        for key, p in (("log", t.log), ("markers", t.markers)):
            if p is None:
                continue
            real = p.resolve()
            if real in owner and owner[real] != t.id:
                raise InputError(f"trials {owner[real]!r} and {t.id!r} read the same {key} file "
                                 f"{p.name!r}; each trial is its own recording", path=manifest,
                                 label=t.id)
            owner[real] = t.id


def _coupling(rows, manifest: Path):
    """``[robot] coupling``: an invertible square matrix of numbers (None when absent)."""
    import numpy as np

    if rows is None:
        return None
    if not (isinstance(rows, list) and rows and all(isinstance(r, list) and len(r) == len(rows) for r in rows)):
        raise InputError("[robot] coupling must be a square list of lists (n x n)", path=manifest,
                         label="coupling")
    C = tuple(tuple(_num(x, "coupling", "[robot]", manifest) for x in r) for r in rows)
    if abs(np.linalg.det(np.array(C))) < 1e-9:
        raise InputError("[robot] coupling is singular; it must be invertible", path=manifest,
                         label="coupling")
    return C


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def write_manifest(path: str | Path, doc: dict, overwrite: bool = False) -> Path:
    """Write a FORMAT v1 manifest from a plain dict (keys as in FORMAT.md; paths relative)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; refusing to overwrite")
    lines = []
    for k in ("format", "name"):
        if k in doc:
            lines.append(f"{k} = {_toml_value(doc[k])}")
    for table in ("robot", "markers"):
        if table in doc:
            lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in doc[table].items()]
    for arr in ("static", "calib", "trial"):
        for tab in doc.get(arr, []):
            lines += ["", f"[[{arr}]]"] + [f"{k} = {_toml_value(v)}" for k, v in tab.items()]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
