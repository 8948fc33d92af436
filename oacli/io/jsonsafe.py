"""Conversion of numpy values and non-finite floats into strict JSON values."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

_isfinite = math.isfinite


def to_json_safe(value: Any) -> Any:
    """Convert numpy arrays/scalars, tuples and mappings to plain JSON values; NaN and ±inf become ``None``.

    The plain types (``float``, ``int``, ``str``, ``bool``, ``None``, ``dict``, ``list``, ``tuple``) and float or
    integer arrays without NaN or infinities take a short path (the same values as the general one, fewer checks:
    the MCAP writer converts every JSON record with this)."""
    cls = type(value)
    if cls is float:
        return value if _isfinite(value) else None
    if cls is str or cls is int or cls is bool or value is None:
        return value
    if cls is dict:
        return {k if type(k) is str else str(k): to_json_safe(v) for k, v in value.items()}
    if cls is list or cls is tuple:
        return [to_json_safe(v) for v in value]
    if cls is np.ndarray:
        kind = value.dtype.kind
        if kind in "iub" or (kind == "f" and bool(np.isfinite(value).all())):
            return value.tolist()  # Python ints, bools or finite floats: nothing to convert
        return to_json_safe(value.tolist())
    return _general(value)


def _general(value: Any) -> Any:
    """:func:`to_json_safe` of any other value (numpy scalars, subclasses of the plain types, other mappings)."""
    if isinstance(value, np.ndarray):
        return to_json_safe(value.tolist())
    if isinstance(value, np.generic):
        return to_json_safe(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): to_json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_json_safe(v) for v in value]
    return value
