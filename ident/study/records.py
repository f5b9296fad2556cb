"""Study records as data: JSON that cannot execute anything when read.

A record holds a finished item's result (plain values, numpy arrays, and the frozen result
dataclasses of this project) in a JSON document::

    {"format": 1, "version": V, "input_hash": H, "outputs": {rel: sha256}, "payload": P,
     "payload_sha256": sha256(canonical JSON of P)}

Arrays are stored as ``{"__array__": dtype, "shape": [...], "data": base64 bytes}`` with a
plain numeric or boolean dtype (``np.frombuffer``: no object arrays, no pickle), so floats round
trip bit for bit. A dataclass is stored as ``{"__dataclass__": "module.Class", "fields": {...}}``
and rebuilt only when ``module`` is one of this project's result modules (or already loaded)
and the name is a dataclass there: a record can choose among our result types, never run code
or import a module. Tuples, dicts with
non-string keys and non-finite floats are tagged likewise.

:func:`read_record` checks, before anything in the payload is used, that the document parses,
that the payload hashes to ``payload_sha256`` and (when known) that the file hashes to the
sha256 the study registered for it, and that its input hash is the current one.
"""
from __future__ import annotations

import base64
import dataclasses
import hashlib
import importlib
import json
import math
from pathlib import Path, PurePath
import re
import sys

import numpy as np

from ident.friction.base import FrictionModel

FORMAT = 1
_MODULE = re.compile(r"^(ident|calib|mocap)(\.[A-Za-z_][A-Za-z0-9_]*)+$")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
#: the modules of the result types a study stores; a record naming another module's type is
#: rebuilt only when that module is already loaded (reading a record never imports a module
#: that has not been imported for other reasons)
RESULT_MODULES = ("calib.pipeline", "calib.axis", "calib.base", "ident.friction.fit",
                  "ident.friction.base", "ident.friction.static", "ident.friction.dynamic",
                  "ident.thesis.campaign_fit")
_DTYPES = {"bool", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64",
           "float16", "float32", "float64", "complex64", "complex128"}


class RecordError(ValueError):
    """A record that is not a valid, verified study record."""


def encode(x):
    """``x`` as JSON-able values (see the module docstring for the tags)."""
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else {"__float__": repr(x)}
    if isinstance(x, PurePath):
        return {"__path__": str(x)}
    if isinstance(x, np.ndarray):
        if x.dtype.name not in _DTYPES:
            raise TypeError(f"cannot store an array of dtype {x.dtype} in a study record")
        a = np.ascontiguousarray(x)
        return {"__array__": a.dtype.name, "shape": list(a.shape),
                "data": base64.b64encode(a.astype(a.dtype.newbyteorder("<")).tobytes()).decode("ascii")}
    if isinstance(x, tuple):
        return {"__tuple__": [encode(v) for v in x]}
    if isinstance(x, list):
        return [encode(v) for v in x]
    if isinstance(x, dict):
        if all(isinstance(k, str) for k in x) and not any(k.startswith("__") for k in x):
            return {k: encode(v) for k, v in x.items()}
        return {"__items__": [[encode(k), encode(v)] for k, v in x.items()]}
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        cls = type(x)
        path = f"{cls.__module__}.{cls.__qualname__}"
        if not _MODULE.match(cls.__module__) or not _NAME.match(cls.__qualname__):
            raise TypeError(f"cannot store a {path} in a study record")
        return {"__dataclass__": path,
                "fields": {f.name: encode(getattr(x, f.name)) for f in dataclasses.fields(x)}}
    cls = type(x)
    if _MODULE.match(cls.__module__) and _NAME.match(cls.__qualname__) and _plain_class(cls) \
            and isinstance(getattr(x, "__dict__", None), dict):
        return {"__object__": f"{cls.__module__}.{cls.__qualname__}",
                "state": {k: encode(v) for k, v in vars(x).items()}}
    raise TypeError(f"cannot store a {type(x).__name__} in a study record")


def _plain_class(cls) -> bool:
    """Classes rebuilt from their attributes alone: the friction models (parameters and
    settings, :class:`ident.friction.base.FrictionModel`)."""

    return isinstance(cls, type) and issubclass(cls, FrictionModel)


def _dataclass(path: str, plain: bool = False):
    mod, _, name = path.rpartition(".")
    if not _MODULE.match(mod) or not _NAME.match(name):
        raise RecordError(f"type {path!r} is not one of jointlab's result types")
    try:
        if mod in RESULT_MODULES:
            importlib.import_module(mod)
        cls = getattr(sys.modules[mod], name)     # never imports anything else
    except (ImportError, AttributeError, KeyError):
        raise RecordError(f"type {path!r} is not one of jointlab's result types") from None
    ok = _plain_class(cls) if plain else (isinstance(cls, type) and dataclasses.is_dataclass(cls))
    if not ok:
        raise RecordError(f"type {path!r} is not one of jointlab's result types")
    return cls


def decode(x):
    """The inverse of :func:`encode`; raises :class:`RecordError` on anything else."""
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    if isinstance(x, list):
        return [decode(v) for v in x]
    if not isinstance(x, dict):
        raise RecordError(f"unexpected {type(x).__name__} in a record")
    if "__float__" in x:
        v = x["__float__"]
        if v not in ("nan", "inf", "-inf"):
            raise RecordError(f"bad float {v!r}")
        return float(v)
    if "__array__" in x:
        dt = x["__array__"]
        if dt not in _DTYPES:
            raise RecordError(f"bad array dtype {dt!r}")
        shape = x.get("shape")
        if not (isinstance(shape, list) and all(isinstance(n, int) and n >= 0 for n in shape)):
            raise RecordError("bad array shape")
        raw = base64.b64decode(str(x.get("data", "")).encode("ascii"), validate=True)
        dtype = np.dtype(dt).newbyteorder("<")
        if len(raw) != dtype.itemsize * int(np.prod(shape, dtype=np.int64)):
            raise RecordError("array data does not fit its shape")
        return np.frombuffer(raw, dtype=dtype).astype(np.dtype(dt)).reshape(shape).copy()
    if "__path__" in x:
        return Path(str(x["__path__"]))
    if "__tuple__" in x:
        return tuple(decode(v) for v in x["__tuple__"])
    if "__items__" in x:
        return {_hashable(decode(k)): decode(v) for k, v in x["__items__"]}
    if "__dataclass__" in x:
        cls = _dataclass(str(x["__dataclass__"]))
        fields = {k: decode(v) for k, v in dict(x.get("fields") or {}).items()}
        names = {f.name for f in dataclasses.fields(cls)}
        if set(fields) - names:
            raise RecordError(f"fields {sorted(set(fields) - names)} are not in {cls.__name__}")
        obj = object.__new__(cls)            # no __init__/__post_init__: the stored values as they were
        for k, v in fields.items():
            object.__setattr__(obj, k, v)
        return obj
    if "__object__" in x:
        cls = _dataclass(str(x["__object__"]), plain=True)
        state = x.get("state")
        if not isinstance(state, dict):
            raise RecordError("bad object state")
        obj = object.__new__(cls)
        obj.__dict__.update({str(k): decode(v) for k, v in state.items()})
        return obj
    return {k: decode(v) for k, v in x.items()}


def _hashable(k):
    return tuple(_hashable(v) for v in k) if isinstance(k, (list, tuple)) else k


def _canonical(payload) -> bytes:
    return json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def dumps_record(input_hash: str, result, version: int, outputs: dict | None = None) -> bytes:
    """The bytes of a record of ``result``."""
    payload = encode(result)
    doc = {"format": FORMAT, "version": version, "input_hash": input_hash, "outputs": outputs or {},
           "payload": payload, "payload_sha256": hashlib.sha256(_canonical(payload)).hexdigest()}
    return json.dumps(doc, allow_nan=False).encode("utf-8")


def read_record(path, input_hash: str, version: int, file_sha: str | None = None):
    """``(record, problem)``: the verified record as ``{"result", "outputs"}`` when it is valid
    and its input hash is ``input_hash``; else ``None`` and why (``None`` when there simply is
    no record for the current inputs, a text when a record failed its check)."""
    path = Path(path)
    if not path.is_file():
        return None, None
    raw = path.read_bytes()
    if file_sha is not None and hashlib.sha256(raw).hexdigest() != file_sha:
        return None, "its bytes differ from what the study wrote"
    try:
        doc = json.loads(raw.decode("utf-8"))
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            return None, "not a study record"
        if doc.get("version") != version or doc.get("input_hash") != input_hash:
            return None, None                      # an older record: the inputs changed
        payload = doc.get("payload")
        if hashlib.sha256(_canonical(payload)).hexdigest() != doc.get("payload_sha256"):
            return None, "its content does not match its recorded hash"
        outputs = doc.get("outputs") or {}
        if not (isinstance(outputs, dict) and all(isinstance(v, str) for v in outputs.values())):
            return None, "bad output list"
        return {"result": decode(payload), "outputs": outputs}, None
    except (UnicodeDecodeError, ValueError, TypeError, KeyError, RecordError, RecursionError,
            OverflowError, AttributeError, IndexError, MemoryError) as exc:
        # any damage (truncated, not UTF-8, a value of the wrong type or size) means recompute
        return None, f"not a valid study record ({type(exc).__name__})"
