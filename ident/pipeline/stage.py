"""A pipeline stage, its context, its cache key and the plain runner.

A :class:`Stage` is a name, the declared inputs it reads (``inputs(ctx) -> dict``: the campaign,
files, settings; their digest :func:`input_key` is the stage's cache key), a ``run`` that turns
those inputs into a typed result and a ``write`` that puts the result's files into a folder.
:func:`ident.pipeline.plan.plan` orders the stages once; two runners execute the list:

- :func:`run_stages` (here): every stage once, in order, into one folder (``jointlab calib``,
  ``mocap``, ``fit``, ``diagnose`` run a slice of the list);
- the study's resumable runner (:class:`ident.study.study.Study`): records, hashes, a lock
  and the parallel map over the same list (docs/architecture.md).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ident.outputs import file_sha256
from mocap.io.campaign import Campaign

__all__ = ["Stage", "Context", "Runtime", "StageReport", "RunReport", "input_key", "run_stages",
           "campaign_files"]


def _always(settings) -> bool:
    return True


def _runs(ctx) -> str | None:
    return None


@dataclass(frozen=True)
class Runtime:
    """What runs a stage without changing its result (never part of a cache key).

    Attributes
    ----------
    sink : viz.Sink, optional
        The recording sink (``--rrd``/``--spawn``).
    executor : optional
        A map executor (:mod:`ident.study.executor`) for per-trial work.
    progress : bool
        Progress bars on stderr.
    """

    sink: object = None
    executor: object = None
    progress: bool = False


@dataclass
class Context:
    """What a stage's ``inputs`` may read: the campaign, the settings, the folder the earlier
    stages wrote into and their results of this run.

    Attributes
    ----------
    campaign : mocap.io.campaign.Campaign
    settings : ident.pipeline.plan.PipelineSettings
    folder : pathlib.Path
        Where the earlier stages' files are (``OUT`` or the output folder's staging folder).
    results : dict
        Stage name -> its result in this run.
    """

    campaign: Campaign
    settings: object
    folder: Path
    results: dict = field(default_factory=dict)
    _robot: object = None

    @property
    def robot(self):
        """The campaign's robot, loaded once."""
        if self._robot is None:
            self._robot = self.campaign.load_robot()
        return self._robot


@dataclass(frozen=True)
class Stage:
    """One stage of the pipeline.

    Attributes
    ----------
    name : str
        The stage's name (``calib``, ``mocap``, ``fits``, ...): a study's stage row and record.
    inputs : callable
        ``inputs(ctx) -> dict``: every input the result depends on, by name (the campaign, files
        as :class:`pathlib.Path`, settings); :func:`input_key` of it is the cache key.
    run : callable
        ``run(inputs, runtime) -> result``: the typed result (writes nothing).
    write : callable
        ``write(result, inputs, folder, runtime) -> dict``: the result's files into ``folder``
        (``inputs``: the declared inputs, e.g. whether to draw plots); name -> path.
    skip : callable
        ``skip(ctx) -> str | None``: why the stage cannot run on this campaign (None: it runs).
    enabled : callable
        ``enabled(settings) -> bool``: the settings ask for the stage.
    output : str
        The file (relative to the study folder) whose presence says the stage wrote; its first
        component is the study's folder of the stage.
    """

    name: str
    inputs: Callable
    run: Callable
    write: Callable
    skip: Callable = _runs
    enabled: Callable = _always
    output: str = ""


# ---------------------------------------------------------------------------------------------
# the cache key: a digest of the declared inputs
# ---------------------------------------------------------------------------------------------
def campaign_files(campaign) -> list:
    """The files a campaign is made of: the manifest, the robot's URDF, drives and MJCF, every
    calibration sweep's, static pose's and trial's marker file and log (None where absent)."""
    files = [campaign.manifest, campaign.urdf, campaign.drives, getattr(campaign, "mjcf", None)]
    for rec in (*campaign.calib, *campaign.static, *campaign.trials):
        files += [getattr(rec, "markers", None), getattr(rec, "log", None)]
    return files


def _plain(value, file_hash: Callable):
    """``value`` as JSON values: files by their digest, folders by their files' digests."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, Campaign):
        return {"campaign": value.name, "files": [_plain(p, file_hash) for p in campaign_files(value)]}
    if isinstance(value, Path):
        if value.is_dir():
            return {"folder": {p.relative_to(value).as_posix(): file_hash(p)
                               for p in sorted(value.rglob("*")) if p.is_file()}}
        return {"file": file_hash(value) if value.is_file() else "missing:" + str(value)}
    if isinstance(value, np.ndarray):
        return {"array": hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest(),
                "shape": list(value.shape)}
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {type(value).__name__: {f.name: _plain(getattr(value, f.name), file_hash)
                                       for f in dataclasses.fields(value)}}
    if isinstance(value, dict):
        return {str(k): _plain(v, file_hash) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple, frozenset, set)):
        items = [_plain(v, file_hash) for v in value]
        return sorted(items, key=json.dumps) if isinstance(value, (set, frozenset)) else items
    raise TypeError(f"a stage input of type {type(value).__name__} has no cache key; declare its "
                    "files or settings instead")


def input_key(inputs: dict, file_hash: Callable = file_sha256) -> str:
    """The cache key of a stage's declared inputs: sha256 over their JSON form, every file by
    its content digest (``file_hash(path)``), so a changed byte in an input file or a changed
    setting gives a new key.

    Parameters
    ----------
    inputs : dict
        Name -> value (:class:`Stage`'s ``inputs``).
    file_hash : callable
        ``path -> str`` digest of a file (default :func:`ident.outputs.file_sha256`; the study
        passes its memoising hasher).

    Returns
    -------
    str
        64 hex digits.

    Raises
    ------
    TypeError
        An input of a type without a cache key.
    """
    doc = _plain(dict(inputs), file_hash)
    return hashlib.sha256(json.dumps(doc, sort_keys=True, allow_nan=True).encode("utf-8")).hexdigest()


# ---------------------------------------------------------------------------------------------
# the plain runner
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StageReport:
    """What one stage did in a run: ``status`` is ``ran`` or ``skipped`` (with ``note``),
    ``paths`` the files it wrote (name -> path), ``seconds`` its wall time."""

    name: str
    status: str
    seconds: float = 0.0
    paths: dict = field(default_factory=dict)
    note: str = ""


@dataclass(frozen=True)
class RunReport:
    """A plain run of stages: per stage its :class:`StageReport` and its typed result."""

    stages: dict
    results: dict

    def __getitem__(self, name: str):
        """The result of stage ``name``."""
        return self.results[name]


def run_stages(stages, ctx: Context, runtime: Runtime = Runtime(), force=()) -> RunReport:
    """Run ``stages`` once, in order, into ``ctx.folder`` (the plain runner of the commands).

    A stage whose ``skip(ctx)`` gives a reason is reported skipped (unless ``force`` names it);
    the others run on their declared inputs and write into ``ctx.folder``, where the next
    stages read their files.

    Parameters
    ----------
    stages : sequence of Stage
        A slice of :func:`ident.pipeline.plan.plan`'s list.
    ctx : Context
    runtime : Runtime
    force : sequence of str
        Stages run even where ``skip`` says they do not apply: a command that asks for one
        stage reports that stage's own error (``jointlab calib`` on a campaign without sweeps).

    Returns
    -------
    RunReport
    """
    reports = {}
    for st in stages:
        t0 = time.perf_counter()
        why = None if st.name in force else st.skip(ctx)
        if why:
            reports[st.name] = StageReport(st.name, "skipped", note=why)
            continue
        inputs = st.inputs(ctx)
        result = st.run(inputs, runtime)
        ctx.results[st.name] = result
        paths = st.write(result, inputs, Path(ctx.folder), runtime) or {}
        reports[st.name] = StageReport(st.name, "ran", time.perf_counter() - t0, dict(paths))
    return RunReport(reports, dict(ctx.results))
