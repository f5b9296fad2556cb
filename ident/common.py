"""One conversion of results to JSON-ready values (used by every writer of result files)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def to_jsonable(x):
    """A result as plain JSON values (every writer of result files goes through this).

    dicts (str keys), lists, numpy arrays and scalars, Paths and objects with ``to_dict()``
    become plain JSON values; non-finite floats become ``None`` (JSON has no NaN).

    Parameters
    ----------
    x : object
        The value to convert.

    Returns
    -------
    object
        ``dict``, ``list``, ``str``, ``int``, ``float``, ``bool`` or ``None``, nested.

    Examples
    --------
    >>> import numpy as np
    >>> to_jsonable({"rms": np.float64(0.25), "q": np.array([1.0, np.nan]), 5: Path("a/b")})
    {'rms': 0.25, 'q': [1.0, None], '5': 'a/b'}
    """
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if np.isfinite(x) else None
    if isinstance(x, Path):
        return str(x)
    if hasattr(x, "to_dict") and callable(x.to_dict):
        return to_jsonable(x.to_dict())
    return x
