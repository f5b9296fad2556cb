"""Typed results of the gap diagnosis; ``to_dict()`` gives diagnosis.json's per-joint entries
(FORMAT.md keys: verdict, effects[].effect/reduction/p_value/significant,
localisation[].regime/share, heldout_rms_nominal, nominal_model)."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field


def _f(x):
    return None if x is None else float(x)


def _fin(x):
    """A float for JSON, None where it is not finite (no power at all)."""
    return float(x) if x is not None and x == x and abs(x) != float("inf") else None


def verdict_line(verdict: str, status: str, size: dict, detectable: dict, alternatives=(), channels=None,
                 extrapolated: float = 0.0, where: str = "") -> str:
    """The verdict in one line, the same wherever it is shown.

    ``stribeck: removes 2.1 noise variances (held-out RMS -14 %)``; with several selected effects
    ``position_ripple: removes 19.7 noise variances (held-out RMS -16 %); then presliding (-32 %
    with it): held-out RMS -32 % in all``; ``none: the gap is at the noise floor (this record could have
    shown an effect of 0.12 noise variances)``; ``unexplained: ...`` (``where``: the variable the
    held-out residual depends on, when known); ``insufficient data: ...`` (``extrapolated``: the
    share of held-out samples the rest of the record cannot predict, when that is the reason).
    Alternatives that explain the same term are named with it."""
    det = detectable.get("torque") if detectable else None
    dtxt = (f"{det:.2g} noise variances" if det is not None and det == det and det != float("inf")
            else "no effect at all")
    if status == "effect":
        s = verdict
        if size:
            so = size.get("size_over_floor")
            s += (f": removes {so:.3g} noise variances" if so is not None else "") + \
                 f" (held-out RMS -{100 * size.get('reduction', 0):.0f} %, {size.get('channel', '')} channel)"
        if alternatives:
            s += "; or " + " or ".join(a["effect"] for a in alternatives) + " (same term: see how to separate)"
        ch = (channels or {}).get(size.get("channel", "")) if size else None
        later = [st for st in (ch.selected[1:] if ch is not None else ())]
        if later and ch.heldout_rms_nominal > 0:
            s += "; then " + ", ".join(f"{st.effect} (-{100 * st.reduction:.0f} % with it)" for st in later)
            s += f": held-out RMS -{100 * (1 - ch.heldout_rms_final / ch.heldout_rms_nominal):.0f} % in all"
        return s
    if status == "unexplained":
        w = f"; {where}" if where else ""
        return (f"unexplained: a gap above the noise floor that no vocabulary effect explains{w} "
                f"(could have shown {dtxt})")
    if status == "insufficient_data" and extrapolated > 0:
        return (f"insufficient data: the record does not repeat its motion ({extrapolated:.0%} of the held-out "
                "samples extrapolate the nominal model)")
    if status == "insufficient_data":
        return f"insufficient data: this record could have shown only an effect of {dtxt}"
    return f"none: the gap is at the noise floor (this record could have shown an effect of {dtxt})"


@dataclass(frozen=True)
class EffectTest:
    """One candidate effect tested against the nominal model (first selection step)."""

    effect: str
    channel: str
    identifiable: bool
    family: str = ""
    note: str = ""
    heldout_rms: float | None = None
    reduction: float | None = None          # 1 - RMS_effect / RMS_nominal, held out
    reduction_step: float | None = None     # same against the model of the current step
    explained_share: float | None = None    # share of the excess over the noise floor removed
    share_step: float | None = None         # ... of the excess the model of the current step leaves
    p_value: float | None = None
    p_adjusted: float | None = None         # Holm over the candidates of the step
    p_min_attainable: float | None = None   # smallest p the test can give with these blocks
    significant: bool = False
    physical: bool = True                   # best fit has the physically meaningful sign
    shape: str = ""
    evidence: dict = field(default_factory=dict)   # signature checks (name -> value/verdict)
    confounded_with: tuple = ()
    separating_experiment: str = ""
    bootstrap_top_share: float = 0.0

    def to_dict(self) -> dict:
        d = {"effect": self.effect, "channel": self.channel, "identifiable": self.identifiable,
             "family": self.family}
        if not self.identifiable:
            d.update(note=self.note, significant=False, p_adjusted=None)
        else:
            d.update(heldout_rms=_f(self.heldout_rms), reduction=_f(self.reduction),
                     reduction_step=_f(self.reduction_step), explained_share=_f(self.explained_share),
                     p_value=_f(self.p_value), p_adjusted=_f(self.p_adjusted),
                     p_min_attainable=_f(self.p_min_attainable), significant=bool(self.significant),
                     physical=bool(self.physical), shape=self.shape)
            if self.note:
                d["note"] = self.note
            if self.evidence:
                d["evidence"] = dict(self.evidence)
        d.update(confounded_with=list(self.confounded_with), separating_experiment=self.separating_experiment,
                 bootstrap_top_share=float(self.bootstrap_top_share))
        return d


@dataclass(frozen=True)
class SelectionStep:
    """An effect that joined the model in forward stepwise selection."""

    effect: str
    channel: str
    heldout_rms: float
    reduction: float
    p_adjusted: float
    explained_share: float
    shape: str
    family: str = ""
    effect_to_floor: float = float("nan")   # held-out variance removed / channel noise-floor variance

    def to_dict(self) -> dict:
        return {"effect": self.effect, "channel": self.channel, "heldout_rms": float(self.heldout_rms),
                "reduction": float(self.reduction), "p_adjusted": float(self.p_adjusted),
                "explained_share": float(self.explained_share), "shape": self.shape, "family": self.family,
                "effect_to_floor": _f(self.effect_to_floor)}


@dataclass(frozen=True)
class ChannelResult:
    """Held-out fit of one channel before and after the selected effects."""

    name: str
    unit: str
    heldout_rms_nominal: float
    heldout_rms_nominal_ci95: tuple
    heldout_rms_final: float
    heldout_rms_final_ci95: tuple
    noise_floor_rms: float
    selected: tuple = ()                                # SelectionStep
    noise_floor_rms_repetitions: float | None = None
    noise_floor_method: str = "white (second differences)"
    n_blocks: int = 0
    p_min_attainable: float | None = None
    extrapolated: float = 0.0     # held-out samples with leverage > 1 (engine.heldout_leverage)
    nuisance: tuple = ()          # terms that joined the nominal, not effects (the payload COM)

    @property
    def remaining_gap_over_noise(self) -> float:
        return float(self.heldout_rms_final / max(self.noise_floor_rms, 1e-300))

    def to_dict(self) -> dict:
        d = {"unit": self.unit, "heldout_rms_nominal": float(self.heldout_rms_nominal),
             "heldout_rms_nominal_ci95": [float(x) for x in self.heldout_rms_nominal_ci95],
             "heldout_rms_final": float(self.heldout_rms_final),
             "heldout_rms_final_ci95": [float(x) for x in self.heldout_rms_final_ci95],
             "noise_floor_rms": float(self.noise_floor_rms), "noise_floor_method": self.noise_floor_method,
             "remaining_gap_over_noise": self.remaining_gap_over_noise,
             "selected": [s.to_dict() for s in self.selected], "n_blocks": int(self.n_blocks),
             "p_min_attainable": _f(self.p_min_attainable)}
        if self.nuisance:
            d["nuisance"] = list(self.nuisance)
        if self.name == "torque":
            d["heldout_extrapolated_share"] = float(self.extrapolated)
            r = self.noise_floor_rms_repetitions
            d["noise_floor_rms_repetitions"] = _f(r)
            if r is not None and r > 0:
                d["remaining_gap_over_repetition_noise"] = float(self.heldout_rms_final / r)
        return d


@dataclass(frozen=True)
class DiagnosisResult:
    """The gap diagnosis of one joint: the verdict, the tests behind it and where the gap lies.

    ``to_dict()`` gives diagnosis.json's per-joint entry (FORMAT.md keys [1]_);
    :meth:`verdict_text` the verdict in one line. Produced by
    :class:`ident.gap.diagnose.GapDiagnosis` [2]_.

    Attributes
    ----------
    verdict : str
        The selected effect (the transmission channel's first selection when it has one, else
        the torque channel's), or ``"none"``.
    nominal_model : str
        Label of the nominal model the gap is measured against.
    n_trials : int
        Trials diagnosed.
    folds : str
        How the held-out folds were formed.
    channels : dict
        Channel name -> :class:`ChannelResult`.
    effects : tuple
        :class:`EffectTest` of every candidate effect, significant first, then by reduction.
    selected : tuple
        Names of the selected effects, by explained share.
    localisation : tuple
        ``({"regime", "share"}, ...)``: the held-out excess per motion regime.
    localisation_method : str
        How the excess was localised.
    localisation_rest : float
        Share of the excess outside every listed regime.
    notes : tuple
        Remarks on the data or the fit.
    insufficient : str
        Why the data cannot settle it (or what stays unexplained); empty otherwise.
    status : str
        ``effect``, ``none``, ``unexplained`` or ``insufficient_data``.
    detectable : dict
        Channel -> smallest detectable effect size (noise variances).
    alternatives : tuple
        ``({"effect", "why", "separate_by"}, ...)``: effects that explain the same term.
    next_experiment : dict
        The experiment that would separate the alternatives or settle the verdict.
    spectrum_bands : tuple
        ``({"band_hz", "excess_share", "excess_over_floor"}, ...)`` of the held-out residual.
    tests : dict
        Channel -> how its units were tested.
    extrapolated : float
        When the verdict is ``insufficient_data`` because the held-out folds extrapolate the
        nominal model: the share of held-out torque samples with a leverage above 1 under their
        fold's training rows (:func:`ident.gap.engine.heldout_leverage`); 0 otherwise.
    series : dict
        Time series for the plots (not in the JSON).
    configuration_localisation : tuple
        ``({"variable", "share", ...}, ...)``: on multi-joint records, the variables the held-out
        residual depends on (each joint's angle, the velocity, acceleration, time), largest first.

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """

    verdict: str
    nominal_model: str
    n_trials: int
    folds: str
    channels: dict                  # name -> ChannelResult
    effects: tuple                  # EffectTest, significant first, then by reduction
    selected: tuple                 # effect names, by explained share
    localisation: tuple             # ({"regime", "share"}, ...)
    localisation_method: str = ""
    localisation_rest: float = 0.0  # share of the excess outside every listed regime
    notes: tuple = ()
    insufficient: str = ""          # why the data cannot settle it (or what stays unexplained)
    status: str = ""                # effect | none | unexplained | insufficient_data
    detectable: dict = field(default_factory=dict)    # channel -> smallest detectable size (noise variances)
    alternatives: tuple = ()        # ({"effect", "why", "separate_by"}, ...): explain the same term
    next_experiment: dict = field(default_factory=dict)
    spectrum_bands: tuple = ()      # ({"band_hz", "excess_share", "excess_over_floor"}, ...)
    tests: dict = field(default_factory=dict)          # channel -> how its units were tested
    extrapolated: float = 0.0       # share of held-out torque samples with leverage > 1 (when it decides)
    series: dict = field(default_factory=dict, repr=False, compare=False)   # plots, not in JSON
    configuration_localisation: tuple = ()   # ({"variable", "share", ...}, ...): what the residual depends on

    @property
    def verdict_status(self) -> str:
        return self.status or ("insufficient_data" if self.insufficient else
                               "effect" if self.verdict != "none" else "none")

    def verdict_text(self) -> str:
        """The verdict in one line, the same wherever it is shown (console, study report,
        diagnosis.md, diagnosis.json's ``verdict_text``)."""
        loc = self.configuration_localisation
        where = (f"depends on {' or '.join([loc[0]['variable']] + list(loc[0].get('tied_with', ())))}"
                 if loc and loc[0].get("share", 0) > 0.1 else "")
        return verdict_line(self.verdict, self.verdict_status, self.effect_size(), self.detectable,
                            self.alternatives, self.channels, self.extrapolated, where)

    def effect_size(self) -> dict:
        """The verdict's size: held-out variance removed over the noise floor, its held-out
        RMS reduction and the channel, from the selection step."""
        if self.verdict == "none":
            return {}
        for ch in self.channels.values():
            for st in ch.selected[:1]:
                if st.effect == self.verdict:
                    return {"size_over_floor": _f(st.effect_to_floor), "reduction": float(st.reduction),
                            "channel": st.channel}
        return {}

    @property
    def heldout_rms_nominal(self) -> float:
        return self.channels["torque"].heldout_rms_nominal

    def effect(self, name: str) -> EffectTest:
        return next(e for e in self.effects if e.effect == name)

    def to_dict(self) -> dict:
        d = {"verdict": self.verdict, "nominal_model": self.nominal_model, "n_trials": int(self.n_trials),
             "folds": self.folds, "channels": {k: c.to_dict() for k, c in self.channels.items()},
             "selected": list(self.selected), "heldout_rms_nominal": float(self.heldout_rms_nominal),
             "localisation": [dict(r) for r in self.localisation],
             "localisation_method": self.localisation_method,
             "localisation_rest": float(self.localisation_rest),
             "effects": [e.to_dict() for e in self.effects]}
        d["verdict_status"] = self.verdict_status
        d["verdict_text"] = self.verdict_text()
        d["detectable_over_floor"] = {k: _fin(v) for k, v in self.detectable.items()}
        if self.effect_size():
            d["verdict_size"] = self.effect_size()
        if self.alternatives:
            d["alternatives"] = [dict(a) for a in self.alternatives]
        if self.next_experiment:
            d["next_experiment"] = dict(self.next_experiment)
        if self.spectrum_bands:
            d["residual_spectrum_bands"] = [dict(b) for b in self.spectrum_bands]
        if self.tests:
            d["tests"] = dict(self.tests)
        if self.verdict_status == "insufficient_data":
            d["insufficient_data"] = self.insufficient
            if self.extrapolated > 0:
                d["heldout_extrapolated_share"] = float(self.extrapolated)
        elif self.verdict_status == "unexplained":
            d["unexplained"] = self.insufficient
        if self.notes:
            d["notes"] = list(self.notes)
        if self.configuration_localisation:
            d["localisation_configuration"] = [dict(r) for r in self.configuration_localisation]
        return d


class FrozenMap(Mapping):
    """A read-only mapping: the nested JSON values a typed result holds (no item can be set,
    replaced or deleted after construction; build another result instead). Pickles as its items.

    Parameters
    ----------
    items : mapping or iterable of pairs, optional
        The entries, in their order.
    """

    __slots__ = ("_items",)

    def __init__(self, items=()):
        self._items = dict(items)

    def __getitem__(self, key):
        return self._items[key]

    def __iter__(self):
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"FrozenMap({self._items!r})"

    def __reduce__(self):
        return FrozenMap, (self._items,)


def freeze(x):
    """``x`` with every mapping made a :class:`FrozenMap` and every list a tuple, recursively
    (scalars, strings and arrays as they are)."""
    if isinstance(x, Mapping):
        return FrozenMap((k, freeze(v)) for k, v in x.items())
    if isinstance(x, (list, tuple)):
        return tuple(freeze(v) for v in x)
    return x


def thaw(x):
    """The inverse of :func:`freeze` as JSON-shaped values: mappings to new ``dict``, tuples and
    lists to new ``list``, recursively."""
    if isinstance(x, Mapping):
        return {k: thaw(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [thaw(v) for v in x]
    return x


@dataclass(frozen=True)
class JointDiagnosis:
    """One joint's entry of ``diagnosis.json``: its gap diagnosis and the campaign-level
    description around it.

    Produced by :func:`ident.gap.campaign_diagnosis.diagnose_single_joint_campaign` (per joint
    over its single-joint trials) and, from the entries of
    :func:`ident.model.multijoint.diagnose_records`, by :meth:`from_dict`; :meth:`to_dict` is the
    one writer of the entry [1]_ (the result's keys, then ``nominal``, then the keys below that
    are set). Frozen: nested values are read-only (:class:`FrozenMap`, tuples).

    Attributes
    ----------
    result : DiagnosisResult or None
        The diagnosis (verdict, tests, localisation) [2]_; None when the entry was read back from
        a written document (``stored`` holds its part).
    nominal : mapping or None
        The nominal model's description with the joint's parameters
        (:meth:`ident.gap.nominal.NominalModel.describe`).
    joint_model : mapping or None
        Single-joint path: rigid or flexible joint (thesis eq. 2-1, 2-2), written as
        ``nominal.joint_model``.
    note_transmission : str
        Why the transmission channel was not diagnosed (no link angles); empty otherwise.
    payload_identified : mapping or None
        Multi-joint records: the payloads identified in the pooled rigid body.
    record : mapping or None
        Multi-joint records: the record's pieces, preprocessing, folds and per-record RMS.
    stored : mapping or None
        The result's part of an entry read back (``result`` is None).
    extra : mapping
        Keys of an entry read back that none of the fields above names (kept, written last).

    References
    ----------
    .. [1] jointlab data format (docs/format.md), sec. What the workbench writes.
    .. [2] jointlab gap diagnosis (docs/gap-diagnosis.md).
    """

    result: DiagnosisResult | None = None
    nominal: Mapping | None = None
    joint_model: Mapping | None = None
    note_transmission: str = ""
    payload_identified: Mapping | None = None
    record: Mapping | None = None
    stored: Mapping | None = None
    extra: Mapping = field(default_factory=FrozenMap)

    def __post_init__(self):
        for name in ("nominal", "joint_model", "payload_identified", "record", "stored", "extra"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, FrozenMap):
                object.__setattr__(self, name, freeze(v))

    @classmethod
    def from_dict(cls, entry: Mapping) -> "JointDiagnosis":
        """A joint's entry as :meth:`to_dict` writes it (a study record, ``diagnosis.json``, the
        entries of :func:`ident.model.multijoint.diagnose_records`), typed; ``to_dict()`` gives
        it back."""
        keys = list(entry)
        cut = keys.index("nominal") if "nominal" in keys else len(keys)
        nominal = entry.get("nominal")
        joint_model = None
        if isinstance(nominal, Mapping) and "joint_model" in nominal:
            joint_model = nominal["joint_model"]
            nominal = {k: v for k, v in nominal.items() if k != "joint_model"}
        tail = {k: entry[k] for k in keys[cut + 1:]}
        return cls(result=None, nominal=nominal, joint_model=joint_model,
                   note_transmission=tail.pop("note_transmission", ""),
                   payload_identified=tail.pop("payload_identified", None),
                   record=tail.pop("record", None), stored={k: entry[k] for k in keys[:cut]},
                   extra=tail)

    def _core(self) -> Mapping:
        return self.result.to_dict() if self.result is not None else (self.stored or FrozenMap())

    @property
    def verdict(self) -> str:
        """The selected effect, or ``"none"``."""
        return self.result.verdict if self.result is not None else self._core().get("verdict", "none")

    @property
    def verdict_text(self) -> str:
        """The verdict in one line (:meth:`DiagnosisResult.verdict_text`)."""
        if self.result is not None:
            return self.result.verdict_text()
        return self._core().get("verdict_text", self.verdict)

    @property
    def verdict_status(self):
        """``effect``, ``none``, ``unexplained`` or ``insufficient_data``."""
        return self.result.verdict_status if self.result is not None else self._core().get("verdict_status")

    @property
    def heldout_rms_nominal(self):
        """Held-out RMS of the nominal model's torque residual, N m."""
        if self.result is not None:
            return float(self.result.heldout_rms_nominal)
        return self._core().get("heldout_rms_nominal")

    @property
    def notes(self) -> tuple:
        """Remarks on the data or the fit."""
        return tuple(self.result.notes if self.result is not None else self._core().get("notes", ()))

    def to_dict(self) -> dict:
        """The joint's ``diagnosis.json`` entry (new plain values)."""
        d = self.result.to_dict() if self.result is not None else thaw(self.stored or {})
        if self.nominal is not None:
            d["nominal"] = thaw(self.nominal)
            if self.joint_model is not None:
                d["nominal"]["joint_model"] = thaw(self.joint_model)
        if self.note_transmission:
            d["note_transmission"] = self.note_transmission
        if self.payload_identified is not None:
            d["payload_identified"] = thaw(self.payload_identified)
        if self.record is not None:
            d["record"] = thaw(self.record)
        d.update(thaw(self.extra))
        return d
