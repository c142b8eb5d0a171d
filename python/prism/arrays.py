"""The checks every array passes before it reaches the native module: NumPy, float32, three
dimensions, C order and the geometry's shape, each failure naming the argument."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np


def check_array(name: str, a: object, shape: Optional[Sequence[int]], axes: str) -> None:
    """Raise ``TypeError`` unless ``a`` is a float32 ``numpy.ndarray``, ``ValueError`` unless it
    has three dimensions, is C-contiguous and (when given) has ``shape``; ``axes`` names the
    expected order in the message (e.g. ``[z][y][x]``)."""
    if not isinstance(a, np.ndarray):
        raise TypeError(f"{name}: expected a numpy.ndarray {axes}, got {type(a).__name__}")
    if a.dtype != np.float32:
        raise TypeError(
            f"{name}: dtype must be float32, got {a.dtype} "
            "(numpy.ascontiguousarray(a, numpy.float32) converts it)"
        )
    if a.ndim != 3:
        raise ValueError(f"{name}: expected 3 dimensions {axes}, got shape {a.shape}")
    if not a.flags.c_contiguous:
        raise ValueError(
            f"{name}: must be C-contiguous {axes} (numpy.ascontiguousarray(a) copies it so)"
        )
    if shape is not None and tuple(a.shape) != tuple(shape):
        raise ValueError(
            f"{name}: shape {tuple(a.shape)} does not match the geometry's {tuple(shape)} {axes}"
        )
