"""Prism from Python: sparse-view spectral CT reconstruction with NumPy arrays in and out.

Conventions are Prism's (docs/geometry.md), the same as the command line's:

* world axes x, y, z in millimetres; the rotation axis is +z through the isocentre; view angle
  θ (radians) puts the cone-beam source at ``DSO·(cos θ, sin θ, 0)``, turning counter-clockwise
  seen from +z;
* volumes are ``float32`` arrays ``[z][y][x]`` of attenuation μ in mm⁻¹;
* projections are ``float32`` arrays ``[view][row][col]`` of line integrals; detector columns
  run along ``(−sin θ, cos θ, 0)``, row 0 is the top of the detector (highest z).

Arrays must be ``float32`` and C-contiguous (``numpy.ascontiguousarray(a, numpy.float32)``):
they are read in place, never copied, and results come back as new arrays without a copy.
Compute runs with the GIL released, so other Python threads go on meanwhile. Bad input raises
``TypeError`` (a wrong array type) or ``ValueError`` (a wrong shape or geometry field, with the
command line's message).

>>> import numpy as np, prism
>>> g = prism.Geometry.cone(dso=200.0, dsd=400.0, rows=16, cols=16, pitch=2.0,
...                         volume=(8, 8, 8), voxel=1.5, angles=prism.full_turn(12))
>>> p = prism.project(np.ones(g.volume_shape, np.float32), g)
>>> p.shape
(12, 16, 16)
"""

from __future__ import annotations

from . import _prism
from .arrays import check_array
from .geometry import (
    Geometry,
    astra_image,
    astra_projections,
    astra_sinogram,
    astra_volume,
    full_turn,
    tigre_projections,
    to_astra_image,
    to_astra_projections,
)
from .run import Run, load_run, query, reconstruct

__version__ = _prism.__version__

__all__ = [
    "Geometry",
    "Run",
    "astra_image",
    "astra_projections",
    "astra_sinogram",
    "astra_volume",
    "backproject",
    "cgls",
    "fdk",
    "full_turn",
    "load_run",
    "project",
    "query",
    "reconstruct",
    "sart",
    "tigre_projections",
    "to_astra_image",
    "to_astra_projections",
]

import numpy as _np


def project(volume: _np.ndarray, geometry: Geometry) -> _np.ndarray:
    """Line integrals of ``volume`` ``[z][y][x]`` (μ, mm⁻¹) through every view of ``geometry``
    (the Joseph projector, as ``prism simulate`` and the iterative methods use it).

    Returns ``[view][row][col]`` float32."""
    check_array("volume", volume, geometry.volume_shape, "[z][y][x]")
    return _prism.project(volume, geometry.to_json())


def backproject(projections: _np.ndarray, geometry: Geometry) -> _np.ndarray:
    """The exact adjoint of :func:`project`: ``⟨project(x), y⟩ = ⟨x, backproject(y)⟩``.

    ``projections`` is ``[view][row][col]``; returns ``[z][y][x]`` float32."""
    check_array("projections", projections, geometry.projection_shape, "[view][row][col]")
    return _prism.backproject(projections, geometry.to_json())


def fdk(projections: _np.ndarray, geometry: Geometry, window: str = "ram_lak") -> _np.ndarray:
    """Filtered backprojection: FDK for a cone beam (Parker weights on a short scan), FBP for a
    parallel beam. ``window`` is one of ``ram_lak``, ``shepp_logan``, ``cosine``, ``hamming``,
    ``hann``. Returns ``[z][y][x]`` float32 (μ, mm⁻¹)."""
    check_array("projections", projections, geometry.projection_shape, "[view][row][col]")
    return _prism.fdk(projections, geometry.to_json(), window)


def sart(
    projections: _np.ndarray,
    geometry: Geometry,
    iterations: int = 10,
    block_size: int = 1,
    relaxation: float = 1.0,
    relaxation_decay: float = 1.0,
    nonneg: bool = True,
    order: str = "random",
    seed: int = 0,
) -> _np.ndarray:
    """SART (``block_size=1``), OS-SART or SIRT (``block_size`` = the view count) from zero.

    ``iterations`` passes over all views; ``relaxation`` λ in (0, 2), multiplied by
    ``relaxation_decay`` after each pass; ``nonneg`` clips negative values after each update;
    ``order`` is ``random`` (a seeded permutation of the blocks each pass) or ``ordered``.
    Returns ``[z][y][x]`` float32."""
    check_array("projections", projections, geometry.projection_shape, "[view][row][col]")
    return _prism.sart(
        projections,
        geometry.to_json(),
        int(iterations),
        int(block_size),
        float(relaxation),
        float(relaxation_decay),
        bool(nonneg),
        str(order),
        int(seed),
    )


def cgls(projections: _np.ndarray, geometry: Geometry, iterations: int = 10) -> _np.ndarray:
    """CGLS (conjugate gradients on the normal equations) from zero, ``iterations`` steps.
    Returns ``[z][y][x]`` float32."""
    check_array("projections", projections, geometry.projection_shape, "[view][row][col]")
    return _prism.cgls(projections, geometry.to_json(), int(iterations))
