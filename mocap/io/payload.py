"""The trial key ``payload_com`` (FORMAT.md): where a trial's payload mass sits."""
from __future__ import annotations


def payload_com(trial) -> tuple:
    """The payload's centre of mass of a trial in the flange frame, metres (FORMAT.md): the
    declared ``payload_com``, else the flange origin; also the origin for ``payload_com =
    "unknown"`` (where a tool must treat the COM as free: :func:`payload_com_unknown`)."""
    v = (getattr(trial, "extra", None) or {}).get("payload_com", (0.0, 0.0, 0.0))
    return (0.0, 0.0, 0.0) if isinstance(v, str) else tuple(float(x) for x in v)


def payload_com_unknown(trial) -> bool:
    """Whether the trial says the lab does not know its payload's centre of mass."""
    return (getattr(trial, "extra", None) or {}).get("payload_com") == "unknown"
