"""JSON helpers shared by the calibration outputs: strict JSON (no NaN), numpy values unwrapped."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["json_default", "json_safe"]


def json_safe(value):
    """``value`` with numpy types unwrapped, tuples as lists and NaN/infinity as None (recursive).

    Parameters
    ----------
    value : object
        Nested dicts, lists, tuples, numpy arrays and scalars.

    Returns
    -------
    object
        The same structure of plain Python values, ready for strict JSON.
    """
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    return value


def json_default(value):
    """``default=`` hook of :func:`json.dumps` for numpy values and paths.

    Parameters
    ----------
    value : object
        A value :mod:`json` cannot write (numpy scalar or array, path...).

    Returns
    -------
    object
        A plain Python equivalent (``str(value)`` as a last resort).
    """
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
