"""Type stubs of the native module (crates/py). Call it through the `prism` package, which checks
arrays and builds the geometry JSON."""

from typing import Any, Callable, Optional

import numpy as np
import numpy.typing as npt

__version__: str

F32 = npt.NDArray[np.float32]

def project(volume: F32, geometry_json: str) -> F32: ...
def backproject(projections: F32, geometry_json: str) -> F32: ...
def fdk(projections: F32, geometry_json: str, window: str) -> F32: ...
def sart(
    projections: F32,
    geometry_json: str,
    iterations: int,
    block_size: int,
    relaxation: float,
    relaxation_decay: float,
    nonneg: bool,
    order: str,
    seed: int,
) -> F32: ...
def cgls(projections: F32, geometry_json: str, iterations: int) -> F32: ...
def check_geometry(geometry_json: str) -> str: ...
def geometry_from_tigre(tigre_json: str, angles_rad: list[float]) -> str: ...
def geometry_from_fan(fan_json: str, angles_rad: list[float]) -> str: ...
def geometry_from_vectors(
    spec_json: str, view_rows: list[list[float]], angles_rad: Optional[list[float]] = None
) -> str: ...
def reconstruct(
    projections: F32,
    geometry_json: str,
    config_yaml: str,
    channels_json: str,
    out: str,
    availability: Optional[npt.NDArray[np.bool_]] = None,
    references: Optional[F32] = None,
    force: bool = False,
    callback: Optional[Callable[[str, Any, Any], None]] = None,
    allow_memory: bool = False,
) -> str: ...
def query(
    run_dir: str,
    coordinate: Optional[float] = None,
    tau: Optional[float] = None,
    kev: Optional[float] = None,
    projections: bool = False,
    extrapolate: bool = False,
) -> tuple[F32, Optional[str], str]: ...
