"""Campaign-level gap diagnosis: group single-joint trials by joint and diagnose each joint."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap.io.angles import read_angles
from mocap.io.errors import InputError
from mocap.io.plausibility import check_angles_dir, check_joints_option

from ident.gap.data import build_joint_data, joint_log
from ident.gap.diagnose import DiagnosisSettings, diagnose_joint
from ident.gap.nominal import check_held_nominal, check_nominal
from ident.gap.report import write_report
from ident.gap.result import FrozenMap, JointDiagnosis, freeze, thaw
from ident.study.executor import progress_bars


def read_angles_csv(path: str | Path) -> tuple[np.ndarray, dict]:
    """An ``angles/<trial id>.csv`` (FORMAT.md) -> (t, {j: q}), read by the one angles reader
    :func:`mocap.io.angles.read_angles`."""
    tr = read_angles(path)
    return tr.time, tr.q


def load_angles_dir(angles_dir: str | Path, trials) -> dict:
    """trial id -> (t, {joint: q}) for every trial with a CSV in ``angles_dir``."""
    angles_dir = Path(angles_dir)
    out = {}
    for t in trials:
        p = angles_dir / f"{t.id}.csv"
        if p.is_file():
            out[t.id] = read_angles_csv(p)
    return out


@dataclass(frozen=True)
class CampaignDiagnosis:
    """The sim-to-real gap diagnosis of a campaign.

    One :class:`ident.gap.result.JointDiagnosis` per joint and what the campaign-level document
    says around them.

    Made by :func:`diagnose_single_joint_campaign` (single-joint trials, per joint) and
    :meth:`from_records` (the multi-joint records' entries of
    :func:`ident.model.multijoint.diagnose_records`), joined by :meth:`with_records`;
    :meth:`to_dict` is the one writer of the ``diagnosis.json`` document [1]_ (``jointlab
    diagnose``, the pipeline's ``diagnosis`` stage, ``jointlab study``), :meth:`write` writes it
    with ``diagnosis.md`` and the plots. Frozen: a changed diagnosis is a new object.

    Attributes
    ----------
    campaign : str
        The campaign's name.
    settings : mapping
        The diagnosis settings as written (:meth:`ident.gap.DiagnosisSettings.to_dict`).
    joints : mapping
        Joint number (int) -> :class:`ident.gap.result.JointDiagnosis`, in the document's order.
    skipped_trials : tuple of str
        Trials no path diagnosed (multi-joint trials when their records were not diagnosed).
    link_angles : bool
        Whether link angles (markers) entered the diagnosis (the transmission channel).
    nominal : mapping or None
        The campaign's nominal model (:meth:`ident.gap.nominal.NominalModel.describe`), on the
        single-joint path.
    multi_joint_trials : tuple of str or None
        The multi-joint records' trials, when the records were diagnosed.
    plan : object
        The campaign's routing (:class:`ident.workflow.Plan`), when known; not written.
    series : mapping
        Joint number -> the plotted series (arrays, or a study's stored reference); not written.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """

    campaign: str
    settings: Mapping
    joints: Mapping
    skipped_trials: tuple = ()
    link_angles: bool = False
    nominal: Mapping | None = None
    multi_joint_trials: tuple | None = None
    plan: object = field(default=None, compare=False)
    series: Mapping = field(default_factory=FrozenMap, repr=False, compare=False)

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "settings", freeze(self.settings))
        set_(self, "joints", FrozenMap((int(j), r if isinstance(r, JointDiagnosis) else JointDiagnosis.from_dict(r))
                                       for j, r in self.joints.items()))
        set_(self, "skipped_trials", tuple(self.skipped_trials))
        set_(self, "link_angles", bool(self.link_angles))
        if self.nominal is not None:
            set_(self, "nominal", freeze(self.nominal))
        if self.multi_joint_trials is not None:
            set_(self, "multi_joint_trials", tuple(self.multi_joint_trials))
        set_(self, "series", FrozenMap((int(j), s) for j, s in self.series.items()))

    @classmethod
    def from_records(cls, campaign: str, settings: Mapping, records: tuple, multi_joint_trials,
                     plan=None) -> "CampaignDiagnosis":
        """The multi-joint records' diagnosis: ``records`` = ``(entries, series)`` of
        :func:`ident.model.multijoint.diagnose_records` ("<joint>" -> entry, "<joint>" ->
        series)."""
        entries, series = records
        return cls(campaign, settings, {int(j): JointDiagnosis.from_dict(r) for j, r in entries.items()},
                   multi_joint_trials=tuple(multi_joint_trials), plan=plan, series=dict(series))

    @classmethod
    def from_dict(cls, doc: Mapping, series=None, plan=None) -> "CampaignDiagnosis":
        """A written ``diagnosis.json`` document, typed (``to_dict()`` gives it back)."""
        return cls(doc["campaign"], doc.get("settings", {}),
                   {int(j): JointDiagnosis.from_dict(r) for j, r in doc.get("joints", {}).items()},
                   skipped_trials=tuple(doc.get("skipped_trials", ())),
                   link_angles=bool(doc.get("link_angles", False)), nominal=doc.get("nominal"),
                   multi_joint_trials=doc.get("multi_joint_trials"), plan=plan, series=series or {})

    def with_records(self, records: "CampaignDiagnosis") -> "CampaignDiagnosis":
        """This (single-joint) diagnosis joined with the multi-joint records' one: the records'
        joints after these (a joint diagnosed on both paths keeps the records' entry, at its
        place), their series, their trials no longer skipped."""
        mine = set(records.multi_joint_trials or ())
        return replace(self, joints={**self.joints, **records.joints},
                       series={**self.series, **records.series},
                       skipped_trials=tuple(t for t in self.skipped_trials if t not in mine),
                       multi_joint_trials=records.multi_joint_trials)

    def summary(self) -> dict:
        """Joint (str) -> verdict, its status and line, held-out RMS of the nominal model, notes."""
        return {str(j): {"verdict": r.verdict, "verdict_status": r.verdict_status,
                         "verdict_text": r.verdict_text, "heldout_rms_nominal": r.heldout_rms_nominal,
                         "notes": list(r.notes)}
                for j, r in self.joints.items()}

    def to_dict(self) -> dict:
        """The ``diagnosis.json`` document (FORMAT.md): ``format``, ``campaign``, ``settings``,
        ``joints`` ("<joint>" -> :meth:`ident.gap.result.JointDiagnosis.to_dict`),
        ``skipped_trials``, ``link_angles``, then ``nominal`` and ``multi_joint_trials`` where
        set. The only place the document is assembled."""
        doc = {"format": 1, "campaign": self.campaign, "settings": thaw(self.settings),
               "joints": {str(j): r.to_dict() for j, r in self.joints.items()},
               "skipped_trials": list(self.skipped_trials), "link_angles": self.link_angles}
        if self.nominal is not None:
            doc["nominal"] = thaw(self.nominal)
        if self.multi_joint_trials is not None:
            doc["multi_joint_trials"] = list(self.multi_joint_trials)
        return doc

    @property
    def report(self) -> dict:
        """:meth:`to_dict` (a new document at each call)."""
        return self.to_dict()

    def series_by_key(self) -> dict:
        """The plotted series keyed as the document's joints ("<joint>")."""
        return {str(j): s for j, s in self.series.items()}

    def write(self, folder, sink=None, plots: dict | None = None) -> dict:
        """``diagnosis.json`` (:meth:`to_dict`), ``diagnosis.md`` and the plots into ``folder``
        (:func:`ident.gap.report.write_report`; ``plots``: the PNGs already drawn there); returns
        name -> path."""
        return write_report(self.to_dict(), self.series_by_key(), Path(folder), sink, plots=plots)


def diagnose_single_joint_campaign(campaign, robot=None, angles: dict | None = None,
                      settings: DiagnosisSettings = DiagnosisSettings(), joints=None,
                      progress: bool = False) -> CampaignDiagnosis:
    """Diagnose every joint that has single-joint trials.

    ``angles`` maps trial id -> (t_marker, {joint: q_link}) (from ``jointlab mocap`` or the
    mocap solver); without it only the torque channel is diagnosed. Returns the
    :class:`CampaignDiagnosis` of those joints (the multi-joint trials listed as skipped).
    """
    robot = robot or campaign.load_robot()
    # a joint whose torque was not logged (FORMAT.md ``unlogged_torque``) has nothing to diagnose
    single = [t for t in campaign.trials if len(t.joints) == 1
              and t.joints[0] not in tuple(getattr(t, "unlogged_torque", ()) or ())]
    skipped = [t.id for t in campaign.trials if len(t.joints) != 1]
    by_joint: dict[int, list] = {}
    for t in single:
        by_joint.setdefault(t.joints[0], []).append(t)
    if joints:
        by_joint = {j: v for j, v in by_joint.items() if j in set(joints)}
    if not by_joint:
        raise InputError("no single-joint trials to diagnose", path=campaign.manifest)

    nominal = check_nominal(settings.nominal, by_joint)
    items = sorted(by_joint.items())
    if progress_bars(progress):   # a bar on a terminal only, not in captured logs
        from tqdm import tqdm
        items = tqdm(items, desc="diagnose", unit="joint")
    out, series = {}, {}
    for j, trials in items:
        # one log read at a time, only the joint's columns kept (JointLog)
        logs = [joint_log(campaign.read_log(t, robot), j) for t in trials]
        ang = None
        if angles:
            ang = {tid: (tq[0], tq[1][j]) for tid, tq in angles.items() if j in tq[1]}
        d = build_joint_data(j, trials, logs, robot, ang)
        res = diagnose_joint(d, settings, gear_ratio=robot.drives[j - 1].gear_ratio)
        out[j] = JointDiagnosis(res, nominal.describe(d), _joint_model(robot, j, d.friction_side),
                                note_transmission="" if d.has_transmission else
                                "no link angles: transmission channel (compliance, backlash, time_offset) not diagnosed")
        series[j] = res.series
    return CampaignDiagnosis(campaign.name, settings.to_dict(), out, skipped_trials=tuple(skipped),
                             link_angles=angles is not None and bool(angles), nominal=nominal.describe(),
                             series=series)


def _joint_model(robot, j: int, friction_side: str) -> dict:
    """diagnosis.json's ``nominal.joint_model`` of joint ``j``: rigid, or flexible at the drive's
    declared stiffness (thesis eq. 2-1, 2-2) with the friction side chosen."""
    k = float(robot.drives[j - 1].extra.get("stiffness", 0.0) or 0.0)
    if friction_side == "rigid":
        return {"kind": "rigid", "text": "no stiffness declared: rigid joint, everything on the motor state"}
    return {"kind": "flexible", "stiffness": k, "friction_side": friction_side,
            "text": f"flexible joint at the declared stiffness {k:g} N m/rad (thesis eq. 2-1, 2-2): "
                    f"rigid-body terms on the link state, friction at the {friction_side} side of the "
                    "spring (chosen by the held-out nominal RMS)"}


def check_diagnose_options(campaign, *, nominal, joints=None, angles=None) -> None:
    """``jointlab diagnose``: held ``--nominal`` values, ``--joints`` of the robot, an
    ``--angles`` folder that fits the campaign (``--seed`` is :class:`DiagnosisSettings`'
    constraint, checked when the settings are made)."""
    check_held_nominal(nominal)
    if not joints and angles is None:
        return
    robot = campaign.load_robot()
    check_joints_option(joints, robot)
    if angles is not None:
        check_angles_dir(angles, campaign, robot)
