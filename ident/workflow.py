"""The workflow layer: one function per campaign-level task, each returning a typed result.

A campaign (:class:`mocap.io.campaign.Campaign`) can be identified along four paths, and which
apply is decided here, once, by :func:`plan`:

``single_joint``
    trials that move one joint: the thesis's one-link model (eq. 2-4) per trial and joint
    (:func:`ident.thesis.campaign_fit.fit_onelink_campaign`); the gap diagnosis pools a joint's trials
    (:func:`ident.gap.campaign_diagnosis.diagnose_single_joint_campaign`).
``indri``
    the dynamic models ``arctan``, ``dm1``, ``dm2`` per joint (Indri & Trapani 2020,
    :func:`ident.indri.campaign_fit.fit_campaign_dynamic`) from single-joint trials of the kinds
    each model needs (constant velocity, reversals, excitation).
``multi_joint``
    one continuous record of several joints: the URDF rigid-body model with per-joint friction
    (:func:`ident.model.multijoint.fit_multijoint_campaign`) and the records' diagnosis
    (:func:`ident.model.multijoint.diagnose_records`).
``coastdown``
    ``kind = "coastdown"`` trials: their own estimator (:mod:`ident.coastdown.campaign_analysis`); the
    friction fit leaves them out.

The tasks:

- :func:`fit_campaign` -> :class:`FitResult` (``jointlab fit``),
- :func:`diagnose_campaign` -> :class:`CampaignDiagnosis` (``jointlab diagnose``),
- :func:`calibrate` -> :class:`CalibrationResult` (``jointlab calib``),
- :func:`solve_angles` -> :class:`CampaignAngles` (``jointlab mocap``).

The command-line commands are shells over these functions: they parse arguments, open the
output folder, choose the executor and the recording sink, call the function, write its result
and print. The functions take a loaded campaign and write nothing; each result's ``write``
(or ``to_dict``) gives the files.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

from calib.pipeline import CalibResult, summary_markdown, write_calib_json
from calib.pipeline import calibrate as _calibrate
from mocap.io.errors import InputError
from mocap.io.plausibility import check_campaign_inputs
from mocap.kinematics import invert_transform
from mocap.quality import summary as mocap_summary
from mocap.solve import solve_trial
from tqdm import tqdm

from ident.coastdown.campaign_analysis import coastdown_trials
from ident.friction.registry import check_models, parse_models
from ident.gap import DiagnosisSettings
from ident.gap.campaign_diagnosis import CampaignDiagnosis
from ident.gap.campaign_diagnosis import diagnose_single_joint_campaign as _diagnose_single
from ident.gap.campaign_diagnosis import load_angles_dir
from ident.indri.campaign_fit import (DYNAMIC_MODELS, DynamicFits, feasible_models, fit_campaign_dynamic,
                                  merge_fits_json, missing_data_sets)
from ident.indri.codegen import export_models_c
from ident.model.multijoint import (MultiJointFits, diagnose_records, fit_multijoint_campaign,
                                    multijoint_trials)
from ident.model.record import DERIVATIVES, RecordSettings, check_campaign_motion
from ident.settings import SEED, AnyOf, Interval, OneOf, Settings
from ident.study.angles import campaign_references
from ident.thesis.campaign_fit import FitsResult
from ident.thesis.campaign_fit import fit_onelink_campaign as _fit_onelink

__all__ = ["PATHS", "Plan", "plan", "parse_models", "check_models", "fit_plans", "subset",
           "prepare_fit", "FitSettings", "FitResult", "fit_campaign", "CampaignDiagnosis",
           "diagnose_campaign", "join_diagnoses", "CalibrationResult",
           "calibrate", "CampaignAngles", "references", "solve_angles"]

#: The identification paths, in the order they are reported, and what each one is.
PATHS = {
    "single_joint": "single-joint trials: the one-link model (thesis eq. 2-4) per trial and joint; "
                    "the gap diagnosis per joint over its trials",
    "indri": "the dynamic models (arctan, dm1, dm2) per joint after Indri & Trapani 2020, from "
             "single-joint constant-velocity, reversal and excitation trials",
    "multi_joint": "multi-joint records: the URDF rigid-body model with per-joint friction, offsets "
                   "and armatures; the records' gap diagnosis",
    "coastdown": "coast-down trials: the coast-down estimator (the friction fit leaves them out)",
}


def _empty_fits() -> dict:
    """A ``fits.json`` document without entries."""
    return {"format": 1, "trials": {}, "summary": []}


# ============================================================================================
# the plan: which paths apply and why
# ============================================================================================
@dataclass(frozen=True)
class Plan:
    """Which identification paths apply to a campaign, which friction models go where, and why.

    Attributes
    ----------
    campaign : str
        The campaign's name.
    single_joint, multi_joint, coastdown : tuple of str
        Ids of the trials that are not multi-joint records (coast-downs included), of those that
        move several joints at once,
        and of the ``kind = "coastdown"`` trials.
    kinds : tuple of str
        The trial kinds among the single-joint trials (what the Indri & Trapani models need).
    paths : tuple of str
        The paths (keys of :data:`PATHS`) that apply, in :data:`PATHS` order.
    reasons : dict
        Path -> one line saying why it applies.
    models : dict
        Path -> the friction models it fits (empty without ``models`` given to :func:`plan`).
    notes : tuple of str
        Routing notes a user should read (a model moved to another path or left out).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] Indri & Trapani 2020 (seeds 001), sec. III.
    .. [3] jointlab workflow layer (docs/workflow.md).
    """

    campaign: str
    single_joint: tuple = ()
    multi_joint: tuple = ()
    coastdown: tuple = ()
    kinds: tuple = ()
    paths: tuple = ()
    reasons: Mapping = field(default_factory=dict)
    models: Mapping = field(default_factory=dict)
    notes: tuple = ()

    @property
    def mixed(self) -> bool:
        """True when multi-joint records and other trials share the campaign."""
        return bool(self.multi_joint) and bool(self.single_joint)

    @property
    def uses_angles(self) -> bool:
        """True when the fit reads link angles (``single_joint`` and ``indri`` paths; a
        multi-joint record's angles are its logged ones)."""
        return bool(self.models.get("single_joint") or self.models.get("indri"))

    @property
    def diagnosis_paths(self) -> tuple:
        """The diagnosis paths: ``single_joint`` (per joint over its single-joint trials) when
        any trial is not a multi-joint record, ``multi_joint`` when there are records."""
        return tuple(p for p, on in (("single_joint", bool(self.single_joint)),
                                     ("multi_joint", bool(self.multi_joint))) if on)

    def to_dict(self) -> dict:
        """The plan as plain JSON values."""
        return {"campaign": self.campaign, "paths": list(self.paths),
                "reasons": dict(self.reasons), "models": {k: list(v) for k, v in self.models.items()},
                "single_joint": list(self.single_joint), "multi_joint": list(self.multi_joint),
                "coastdown": list(self.coastdown), "kinds": list(self.kinds),
                "notes": list(self.notes)}

    def describe(self) -> str:
        """One line per path that applies: the path, its models and why."""
        lines = []
        for p in self.paths:
            ms = self.models.get(p)
            lines.append(f"{p}: {self.reasons[p]}" + (f" (models {', '.join(ms)})" if ms else ""))
        return "\n".join(lines + [f"note: {n}" for n in self.notes])


THESIS_MODELS = ("cv", "stribeck", "hyperbolic")


def default_models(campaign) -> tuple[tuple, str | None]:
    """The friction models ``jointlab fit`` runs without ``--models``, chosen from the
    campaign's shape, and the one line that says why when it is not the thesis set.

    A campaign whose trials move several joints at once and that has no markers (a controller
    log of a whole arm) gets ``cv`` only: Coulomb + viscous is linear in its parameters and
    identifiable from such logs, while the thesis's Stribeck and hyperbolic laws (eq. 2-5, 2-6
    of [1]_) give impossible values on them (a negative Stribeck ``Fs`` of thousands of N m on
    a UR10e log); they stay available with ``--models``. Otherwise the thesis set
    :data:`THESIS_MODELS`.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 to 2-6.
    """
    if multijoint_trials(campaign) and not campaign.has_markers:
        return ("cv",), ("a multi-joint campaign without markers: fitting cv only (Stribeck and "
                         "hyperbolic laws are not identifiable from whole-arm logs; ask for them "
                         "with --models)")
    return THESIS_MODELS, None


def plan(campaign, models=None, *, export_c: bool = False) -> Plan:
    """Decide which paths apply to ``campaign`` (and, given ``models``, which model goes where).

    Without ``models`` the plan says what the data allow: every path that has trials. With
    ``models`` it is the friction fit's routing, the one ``jointlab fit`` runs:

    - multi-joint records alone: every model on the rigid-body path;
    - multi-joint records beside other trials: refused (two manifests);
    - otherwise ``arctan``, ``dm1``, ``dm2`` on the Indri & Trapani path and the rest per trial;
      ``arctan`` goes per trial (a static law through eq. 2-4) when there is no single-joint
      constant-velocity trial; dynamic models whose data sets are missing are left out with a
      note (refused when nothing else is asked).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    models : sequence of str, optional
        The friction models asked for (see :func:`parse_models`).
    export_c : bool
        A C export is asked for (not available on the multi-joint path).

    Returns
    -------
    Plan

    Raises
    ------
    InputError
        A contradiction between the models (or ``export_c``) and the campaign's trials.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] Indri & Trapani 2020 (seeds 001), sec. III.
    .. [3] jointlab workflow layer (docs/workflow.md).

    Examples
    --------
    >>> from pathlib import Path
    >>> from mocap.io.campaign import load_campaign
    >>> import ident
    >>> demo = load_campaign(Path(ident.__file__).parents[1] / "fixtures" / "demo")
    >>> plan(demo).paths
    ('single_joint',)
    >>> p = plan(demo, ("cv", "arctan"))
    >>> dict(p.models)
    {'single_joint': ('cv', 'arctan')}
    """
    multi = multijoint_trials(campaign)
    multi_ids = tuple(t.id for t in multi)
    others = [t for t in campaign.trials if t not in multi]
    single = tuple(t for t in others if len(t.joints) == 1)
    coast = tuple(t.id for t in coastdown_trials(campaign))
    kinds = tuple(sorted({t.kind for t in single}))
    base = dict(campaign=campaign.name, single_joint=tuple(t.id for t in others),
                multi_joint=multi_ids, coastdown=coast, kinds=kinds)
    fit_single = [t for t in others if t.kind != "coastdown"]
    reasons = {}
    if fit_single:
        reasons["single_joint"] = f"{len(fit_single)} single-joint trial(s)"
    feasible = feasible_models(DYNAMIC_MODELS, kinds)
    if feasible:
        reasons["indri"] = f"single-joint trials of kinds {', '.join(kinds)} allow {', '.join(feasible)}"
    if multi:
        reasons["multi_joint"] = f"{len(multi)} trial(s) move several joints at once"
    if coast:
        reasons["coastdown"] = f"{len(coast)} coast-down trial(s)"
    if models is None:
        return Plan(**base, paths=tuple(p for p in PATHS if p in reasons), reasons=reasons)

    models = tuple(models)
    if multi:
        if others:
            raise InputError(f"the campaign mixes multi-joint trials ({multi[0].id!r}, ...) with "
                             "single-joint ones; fit them from two manifests", path=campaign.manifest)
        check_models(models)
        if export_c:
            raise InputError("--export-c is not available for multi-joint records")
        return Plan(**base, paths=("multi_joint",) + (("coastdown",) if coast else ()),
                    reasons={k: v for k, v in reasons.items() if k in ("multi_joint", "coastdown")},
                    models={"multi_joint": models})
    dyn = tuple(m for m in models if m in DYNAMIC_MODELS)
    one = tuple(m for m in models if m not in DYNAMIC_MODELS)
    notes = []
    if "arctan" in dyn and not any(t.kind == "constant_velocity" for t in single):
        # Indri & Trapani fit arctan to constant-velocity moves (data set 1); without them the
        # static arctan law is fitted per trial like the thesis's static laws (eq. 2-4)
        dyn = tuple(m for m in dyn if m != "arctan")
        one = one + ("arctan",)
        notes.append("arctan: no constant_velocity trials (Indri & Trapani data set 1): fitted "
                     "per trial through the one-link model (eq. 2-4) with the static laws")
    if dyn and not feasible_models(dyn, kinds):
        skip = f"{', '.join(dyn)} not identified ({missing_data_sets(dyn, kinds)})"
        if not one:
            raise InputError(skip, path=campaign.manifest)
        notes.append(skip)
        dyn = ()
    routed = {"single_joint": one, "indri": dyn}
    reasons = dict(reasons)
    if one:
        reasons.setdefault("single_joint", "models asked for, but no single-joint trial to fit")
    return Plan(**base, paths=tuple(p for p in PATHS if routed.get(p) or (p == "coastdown" and coast)),
                reasons=reasons, models={k: v for k, v in routed.items() if v}, notes=tuple(notes))


def subset(campaign, ids):
    """The campaign with only the trials whose id is in ``ids`` (campaign order kept).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    ids : iterable of str
        Trial ids to keep.

    Returns
    -------
    mocap.io.campaign.Campaign
        A copy holding those trials.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. campaign.toml.
    """
    keep = set(ids)
    return dataclasses.replace(campaign, trials=tuple(t for t in campaign.trials if t.id in keep))


def fit_plans(campaign, models) -> tuple:
    """The friction fit's plans of a campaign: one :func:`plan` per manifest it is fitted from.

    A mixed campaign (multi-joint records beside other trials, which :func:`plan` refuses to fit
    as one) gives the plan of its other trials, then that of its records; any other campaign
    its one plan. ``jointlab fit`` fits one manifest; ``jointlab study`` fits every part.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    models : sequence of str

    Returns
    -------
    tuple of Plan

    Raises
    ------
    InputError
        As :func:`plan`, for any part.

    References
    ----------
    .. [1] jointlab workflow layer (docs/workflow.md).
    """
    whole = plan(campaign)
    if not whole.mixed:
        return (plan(campaign, models),)
    return tuple(plan(subset(campaign, ids), models) for ids in (whole.single_joint, whole.multi_joint))


# ============================================================================================
# friction fits
# ============================================================================================
@dataclass(frozen=True)
class FitSettings(Settings):
    """Settings of :func:`fit_campaign`.

    :attr:`constraints` is checked at construction (:mod:`ident.settings`).

    Parameters
    ----------
    n_starts : int
        Multi-start count of the nonlinear fits.
    seed : int
        Seed of the multi-starts.
    sync : {"clock", "estimate"}
        Single-joint trials: the marker-to-robot clock as recorded (+ the trial's
        ``time_offset``) or estimated.
    derivatives : {"savgol", "logged"}
        Multi-joint records: velocities from the angles or the logged ``qd_<j>``.
    window : "auto" or float or str
        Multi-joint records: the Savitzky-Golay window, s (a string is parsed).
    v_zero : "auto" or float or str
        Multi-joint records: the low-speed cut, a fraction of the 99th-percentile speed in
        ``[0, 1)`` (a string is parsed).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] jointlab workflow layer (docs/workflow.md).
    """

    n_starts: int = 8
    seed: int = 0
    sync: str = "clock"
    derivatives: str = "savgol"
    window: object = "auto"
    v_zero: object = "auto"

    #: field -> (command-line option, constraint), checked at construction
    constraints = {
        "n_starts": ("--starts", Interval(1, integer=True)),
        "seed": ("--seed", SEED),
        "sync": ("--sync", OneOf("clock", "estimate")),
        "derivatives": ("--derivatives", OneOf(*DERIVATIVES)),
        "window": ("--window", AnyOf(OneOf("auto"), Interval(0, closed="right", parse=True, note="s"))),
        "v_zero": ("--v-zero", AnyOf(OneOf("auto"), Interval(0, 1, closed="left", parse=True))),
    }

    def record_settings(self) -> tuple:
        """``(RecordSettings, v_zero)`` of the multi-joint path, the text values parsed (both
        checked at construction: ``auto`` or seconds > 0, ``auto`` or a fraction in ``[0, 1)``)."""
        window = self.window if self.window == "auto" else float(self.window)
        v_zero = self.v_zero if self.v_zero == "auto" else float(self.v_zero)
        return RecordSettings(derivatives=self.derivatives, window_s=window), v_zero


@dataclass(frozen=True)
class FitResult:
    """The friction fits of a campaign along the paths its :class:`Plan` chose.

    Attributes
    ----------
    plan : Plan
        The routing that produced this result.
    onelink : ident.thesis.campaign_fit.FitsResult or None
        Per trial and joint, the one-link fits (``single_joint`` path).
    indri : ident.indri.campaign_fit.DynamicFits or None
        Per joint, the Indri & Trapani fits (``indri`` path).
    rigidbody : ident.model.multijoint.MultiJointFits or None
        Per record, the rigid-body fits (``multi_joint`` path).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] Indri & Trapani 2020 (seeds 001), sec. III.
    .. [3] jointlab data format (docs/format.md).
    """

    plan: Plan
    onelink: FitsResult | None = None
    indri: DynamicFits | None = None
    rigidbody: MultiJointFits | None = None

    def to_dict(self) -> dict:
        """The ``fits.json`` document (FORMAT.md): trial entries, the Indri ``joints`` key."""
        if self.rigidbody is not None:
            return self.rigidbody.merge_into(_empty_fits())
        doc = self.onelink.to_dict() if self.onelink is not None else _empty_fits()
        return merge_fits_json(doc, self.indri) if self.indri is not None else doc

    def write(self, folder, plots: bool = True, sink=None) -> dict:
        """Write ``fits.json`` and each path's reports into ``folder``.

        Parameters
        ----------
        folder : path-like
            An existing folder.
        plots : bool
            Single-joint path: the friction-vs-speed PNGs.
        sink : viz.Sink, optional
            Receives the Indri & Trapani figures.

        Returns
        -------
        dict
            Name -> written path (``fits`` always; ``indri``, ``rigidbody``, ... per path).
        """
        folder = Path(folder)
        fits = folder / "fits.json"
        if self.rigidbody is not None:
            fits.write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False), encoding="utf-8")
            return {"fits": fits, **self.rigidbody.write(folder)}
        paths = self.onelink.write(folder, plots=plots) if self.onelink is not None else {}
        if self.indri is not None:
            paths["fits"] = fits
            fits.write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False), encoding="utf-8")
            paths["indri"] = self.indri.write_reports(folder, sink=sink)
        return paths

    def export_c(self, folder, dt: float | None = None) -> tuple:
        """C99 export (:func:`ident.indri.codegen.export_models_c`) of every representable
        model: the dynamic models (``joint<j>_<model>``) at the sample time ``dt`` (default: the
        identification data's) and the per-trial ``cv`` fits (``<trial>_<joint>_cv``).

        Returns
        -------
        tuple
            (written paths, a note or None when ``dt`` differs from the identification's).
        """
        if self.rigidbody is not None:
            raise InputError("--export-c is not available for multi-joint records")
        tree, note = {}, None
        if self.indri is not None:
            tree.update(self.indri.export_models())
            ident_dt = sorted({round(d.dt, 12) for d in self.indri.data.values()})
            if dt is None:
                if len(ident_dt) > 1:
                    raise InputError("the joints were identified at different sample times "
                                     f"{ident_dt}; give --export-dt")
                dt = ident_dt[0]
            elif any(abs(dt - x) > 1e-9 * max(dt, x) for x in ident_dt):
                note = (f"--export-dt {dt:g} s differs from the identification sample time "
                        f"{', '.join(f'{x:g}' for x in ident_dt)} s: the discrete damping absorbs "
                        "Ts/2 (ident.indri.estimator), re-identify at the controller's rate")
        if self.onelink is not None:
            for e in self.onelink.entries:
                tree.setdefault(e.task.trial, {}).setdefault(str(e.task.joint), {}).update(
                    {m: f for m, f in e.fits.items() if m == "cv"})
        try:
            return export_models_c(tree, folder, dt=dt), note
        except ValueError as exc:
            raise InputError(f"--export-c: {exc}", path=folder) from None


def prepare_fit(campaign, models, *, angles=None, export_c: bool = False) -> Plan:
    """Check a campaign's logs for a friction fit and plan it (cheap; before any output).

    Braked joints must stay still (:func:`ident.model.record.check_campaign_motion`), every log
    must be plausible (:func:`mocap.io.plausibility.check_campaign_inputs`), then :func:`plan`;
    an angles folder the plan reads must be a folder.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    models : sequence of str
    angles : path-like, optional
        The link-angles folder to be given to :func:`fit_campaign`.
    export_c : bool
        A C export will be asked for.

    Returns
    -------
    Plan

    References
    ----------
    .. [1] jointlab workflow layer (docs/workflow.md).
    """
    check_campaign_motion(campaign, campaign.load_robot().n)
    check_campaign_inputs(campaign, markers=False)
    p = plan(campaign, models, export_c=export_c)
    if p.uses_angles and angles is not None and not Path(angles).is_dir():
        raise InputError("--angles must be a folder", path=angles)
    return p


def fit_campaign(campaign, *, models=("cv", "stribeck", "hyperbolic"), angles=None,
                 settings: FitSettings = FitSettings(), plan: Plan | None = None, sink=None,
                 executor=None) -> FitResult:
    """Fit friction models to a campaign along the paths :func:`plan` chooses.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
        The loaded campaign.
    models : sequence of str
        Friction models (:func:`parse_models`); the plan's when ``plan`` is given.
    angles : path-like, optional
        Folder of ``angles/<trial id>.csv`` link angles (single-joint and Indri paths; default:
        the motor angles stand in).
    settings : FitSettings
    plan : Plan, optional
        From :func:`prepare_fit`; default: checked and planned here.
    sink : viz.Sink, optional
        Recording sink.
    executor : optional
        Anything with ``map(fn, iterable)`` for the per-trial fits.

    Returns
    -------
    FitResult

    References
    ----------
    .. [1] PA10 thesis (seeds 002), eq. 2-4 and Tables 5-1 to 5-3.
    .. [2] Indri & Trapani 2020 (seeds 001), sec. III.
    .. [3] jointlab workflow layer (docs/workflow.md).
    """
    p = plan if plan is not None else prepare_fit(campaign, models, angles=angles)
    if "multi_joint" in p.models:
        rs, v_zero = settings.record_settings()
        res = fit_multijoint_campaign(campaign, p.models["multi_joint"], record=rs, seed=settings.seed,
                                      v_zero=v_zero, n_starts=settings.n_starts, sink=sink)
        return FitResult(p, rigidbody=res)
    one = dyn = None
    if p.models.get("single_joint"):
        one = _fit_onelink(campaign, angles, p.models["single_joint"], sink=sink, executor=executor,
                           n_starts=settings.n_starts, seed=settings.seed, sync=settings.sync)
    if p.models.get("indri"):
        dyn = fit_campaign_dynamic(campaign, angles_dir=angles, sink=sink, models=p.models["indri"])
    return FitResult(p, onelink=one, indri=dyn)


# ============================================================================================
# gap diagnosis
# ============================================================================================
def link_angles(campaign, robot, angles=None, sink=None, progress: bool = True) -> dict:
    """trial id -> (marker time, {joint: link angle}): read from an angles folder, or solved
    from the markers (:func:`solve_angles`)."""
    if angles is not None:
        return load_angles_dir(angles, campaign.trials)
    return solve_angles(campaign, robot=robot, sink=sink, progress=progress,
                        log_camera=False).link_angles()


def diagnose_campaign(campaign, *, robot=None, angles=None, markers: bool = True,
                      settings: DiagnosisSettings = DiagnosisSettings(), joints=None, sink=None,
                      progress: bool = True) -> CampaignDiagnosis:
    """Diagnose the sim-to-real gap of every joint along the paths :func:`plan` chooses.

    Single-joint trials go through :func:`ident.gap.campaign_diagnosis.diagnose_single_joint_campaign` (per joint),
    multi-joint records through :func:`ident.model.multijoint.diagnose_records`; a campaign with
    both gets one report.

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    robot : mocap.robot.Robot, optional
        Default: the campaign's.
    angles : path-like or dict, optional
        An angles folder (``jointlab mocap``), or trial id -> (t, {joint: q}) (used as given);
        default: solved from the markers here.
    markers : bool
        False: no folder is read and nothing solved (the torque channel only, unless ``angles``
        is a dict); a campaign without markers is diagnosed on the torque channel.
    settings : ident.gap.DiagnosisSettings
    joints : sequence of int, optional
        The joints to diagnose (default: every one).
    sink : viz.Sink, optional
    progress : bool
        Progress bars on stderr.

    Returns
    -------
    CampaignDiagnosis

    References
    ----------
    .. [1] jointlab gap diagnosis (docs/gap-diagnosis.md).
    .. [2] jointlab workflow layer (docs/workflow.md).
    """
    robot = robot if robot is not None else campaign.load_robot()
    ang = None
    if isinstance(angles, dict):
        ang = angles
    elif markers and campaign.has_markers:
        ang = link_angles(campaign, robot, angles, sink)
    check_campaign_motion(campaign, robot.n)
    p = plan(campaign)
    paths = p.diagnosis_paths
    single = records = None
    if "single_joint" in paths or "multi_joint" not in paths:
        single = _diagnose_single(campaign, robot, ang, settings, joints=joints, progress=progress)
    if "multi_joint" in paths:
        records = diagnose_records(campaign, robot, settings, joints=joints, progress=progress)
    return join_diagnoses(p, settings, single, records)


def join_diagnoses(plan: Plan, settings: DiagnosisSettings, single: CampaignDiagnosis | None = None,
                   records: tuple | None = None) -> CampaignDiagnosis:
    """A campaign's diagnosis from its paths' parts.

    The one place that joins them (:func:`diagnose_campaign`, ``jointlab study``).

    Parameters
    ----------
    plan : Plan
        The campaign's plan (:func:`plan` without models).
    settings : ident.gap.DiagnosisSettings
    single : CampaignDiagnosis, optional
        The single-joint trials' diagnosis
        (:func:`ident.gap.campaign_diagnosis.diagnose_single_joint_campaign`, or the same
        assembled from its per-joint parts).
    records : tuple, optional
        ``(entries, series)`` of the multi-joint records
        (:func:`ident.model.multijoint.diagnose_records`); a joint diagnosed on both paths
        keeps the records' entry.

    Returns
    -------
    CampaignDiagnosis
        With ``plan``; its :meth:`~ident.gap.campaign_diagnosis.CampaignDiagnosis.to_dict` is the
        ``diagnosis.json`` document.

    References
    ----------
    .. [1] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """
    rec = None
    if records is not None:
        rec = CampaignDiagnosis.from_records(plan.campaign, settings.to_dict(), records, plan.multi_joint)
    if single is None:
        single = rec if rec is not None else CampaignDiagnosis(plan.campaign, settings.to_dict(), {})
    elif rec is not None:
        single = single.with_records(rec)
    return dataclasses.replace(single, plan=plan)


# ============================================================================================
# calibration
# ============================================================================================
@dataclass(frozen=True)
class CalibrationResult:
    """The camera-to-base calibration of a campaign (:class:`calib.pipeline.CalibResult`).

    Attributes
    ----------
    result : calib.pipeline.CalibResult
        Axes, base placement, ``T_camera_base`` (``p_camera = T_camera_base @ p_base``), its
        uncertainty, the warnings.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), ch. 3, eq. 3-1 to 3-3 (the joint 1/2 axes place the base).
    .. [2] jointlab data format (docs/format.md).
    """

    result: CalibResult

    @property
    def T_camera_base(self):
        """4x4 homogeneous transform of base-frame points into the camera frame."""
        return self.result.T_camera_base

    @property
    def warnings(self) -> tuple:
        """The calibration's warnings (short sweeps, weak geometry, ...)."""
        return tuple(self.result.warnings)

    def to_dict(self) -> dict:
        """The ``calib.json`` document (FORMAT.md)."""
        return self.result.to_dict()

    def markdown(self, warnings: bool = False) -> str:
        """The human summary (:func:`calib.pipeline.summary_markdown`)."""
        return summary_markdown(self.result, warnings=warnings)

    def write(self, folder) -> Path:
        """``calib.json`` into ``folder``; returns its path."""
        return write_calib_json(Path(folder) / "calib.json", self.result)


def calibrate(campaign, *, robot=None, method: str = "auto", noise_mm: float | None = None,
              min_sweep_deg: float = 15.0, cross_check: bool = False, urdf_tol_mm: float = 0.0,
              trust_urdf: bool = False, deflection: bool = False, sink=None) -> CalibrationResult:
    """Place the robot base in the camera frame from the campaign's ``[[calib]]`` sweeps.

    The joint 1 sweep then the joint 2 sweep give two axes (:func:`calib.pipeline.calibrate`).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    robot : mocap.robot.Robot, optional
    method : {"auto", "cluster", "circle"}
        Axis estimator.
    noise_mm : float, optional
        3-D RMS marker noise for the Cramer-Rao bound (default: from the residuals).
    min_sweep_deg : float
        Shorter sweeps are refused.
    cross_check : bool
        Also solve the hand-eye peer and report the difference.
    urdf_tol_mm : float
        Standard uncertainty of the URDF's axis placement, added as a model error.
    trust_urdf : bool
        Trust the URDF's J1-J2 geometry: no model error estimated from the measured J1-J2
        discrepancy (``urdf_model_error=False`` of :func:`calib.pipeline.calibrate_sweeps`).
    deflection : bool
        Undo the joints' static deflection under gravity at the declared stiffness
        (:func:`calib.pipeline.compensate_deflection`).
    sink : viz.Sink, optional

    Returns
    -------
    CalibrationResult

    References
    ----------
    .. [1] PA10 thesis (seeds 002), ch. 3, eq. 3-1 to 3-3 (the joint 1/2 axes place the base).
    """
    robot = robot if robot is not None else campaign.load_robot()
    return CalibrationResult(_calibrate(campaign, robot, method=method, sink=sink, noise_mm=noise_mm,
                                        min_sweep_deg=min_sweep_deg, cross_check=cross_check,
                                        urdf_tol_mm=urdf_tol_mm, urdf_model_error=not trust_urdf,
                                        deflection=deflection))


# ============================================================================================
# link angles
# ============================================================================================
@dataclass(frozen=True)
class CampaignAngles:
    """Link angles of a campaign's trials from their markers.

    Attributes
    ----------
    references : mocap.references.References
        The static-pose references (marker positions in link frames, ``T_camera_base``).
    camera_from : str
        Where the camera pose came from: ``calib.json`` (given), ``static_poses`` or
        ``calib_sweeps``.
    trials : tuple of mocap.solve.AnglesResult
        One per solved trial, in campaign order.

    References
    ----------
    .. [1] PA10 thesis (seeds 002), ch. 3, eq. 3-3 to 3-5.
    .. [2] jointlab data format (docs/format.md).
    """

    references: object
    camera_from: str
    trials: tuple = ()

    def summary(self) -> dict:
        """The ``mocap.json`` document (:func:`mocap.quality.summary` + ``camera_from``)."""
        doc = mocap_summary(list(self.trials), self.references)
        doc["camera_from"] = self.camera_from
        return doc

    def link_angles(self) -> dict:
        """trial id -> (marker time, {joint: link angle}) (flagged frames NaN)."""
        return {r.trial_id: (r.time, {j: r.q_link[:, k] for k, j in enumerate(r.joints)})
                for r in self.trials}

    def write(self, folder) -> dict:
        """``angles/<trial>.csv`` (FORMAT.md), ``references.json`` and ``mocap.json`` into
        ``folder`` (the trial ids were checked as output names by the caller's output folder);
        returns name -> path (``angles``: the folder)."""
        folder = Path(folder)
        for res in self.trials:
            name = f"{res.trial_id}.csv"          # an id is data: one plain file name, never a path
            if Path(name).name != name or name.startswith(".") or "\\" in name:
                raise InputError(f"trial id {res.trial_id!r} cannot name a file in angles/", label=res.trial_id)
            res.write_csv(folder / "angles" / name, overwrite=True)
        (folder / "references.json").write_text(json.dumps(self.references.to_dict(), indent=1),
                                                encoding="utf-8")
        (folder / "mocap.json").write_text(json.dumps(self.summary(), indent=1), encoding="utf-8")
        return {"angles": folder / "angles", "references": folder / "references.json",
                "mocap": folder / "mocap.json"}


def references(campaign, *, robot=None, T_camera_base=None) -> tuple:
    """The static-pose references (thesis eq. 3-4) and where the camera pose came from.

    The camera pose is ``T_camera_base`` when given, else estimated from the static poses when
    they fix it, else from the ``[[calib]]`` sweeps (:func:`ident.study.angles.campaign_references`).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    robot : mocap.robot.Robot, optional
        Default: the campaign's.
    T_camera_base : array_like, optional
        4x4, from ``calib.json``.

    Returns
    -------
    tuple
        (:class:`mocap.references.References`, ``"calib.json"``, ``"static_poses"`` or
        ``"calib_sweeps"``).

    References
    ----------
    .. [1] PA10 thesis (seeds 002), ch. 3, eq. 3-3 to 3-5.
    """
    robot = robot if robot is not None else campaign.load_robot()
    return campaign_references(campaign, robot, T_camera_base)


def solve_angles(campaign, *, robot=None, T_camera_base=None, refs=None, trials=None, sink=None,
                 progress: bool = False, log_camera: bool = True, **solver) -> CampaignAngles:
    """Link angles of every trial (thesis eq. 3-4 references, eq. 3-5 per-frame solve).

    Parameters
    ----------
    campaign : mocap.io.campaign.Campaign
    robot : mocap.robot.Robot, optional
    T_camera_base : array_like, optional
        4x4, from ``calib.json``; default: see :func:`references`.
    refs : tuple, optional
        :func:`references`'s (references, camera_from), computed here by default.
    trials : sequence of Trial, optional
        Default: every trial.
    sink : viz.Sink, optional
    progress : bool
        A progress bar on stderr.
    log_camera : bool
        Log the camera's pose in the base frame to ``sink`` (``world/camera``).
    **solver
        Settings of :func:`mocap.solve.solve_trial` (``refine``, ``min_markers``, ...).

    Returns
    -------
    CampaignAngles

    References
    ----------
    .. [1] PA10 thesis (seeds 002), ch. 3, eq. 3-3 to 3-5.
    """
    robot = robot if robot is not None else campaign.load_robot()
    refs, camera_from = (refs if refs is not None
                         else references(campaign, robot=robot, T_camera_base=T_camera_base))
    trials = list(campaign.trials if trials is None else trials)
    if log_camera and sink is not None and sink.enabled:
        # world = the robot base frame; the camera entity's pose in it is T_base_camera
        sink.transform("world/camera", invert_transform(refs.T_camera_base))
    it = trials
    if progress:
        it = tqdm(trials, desc="mocap", unit="trial", leave=False)
    results = []
    for tr in it:       # a for loop: a failed solve closes the progress bar before the error line
        results.append(solve_trial(campaign, tr, refs, sink=sink, robot=robot, **solver))
    return CampaignAngles(refs, camera_from, tuple(results))
