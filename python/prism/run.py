"""Any method of ``prism recon`` on NumPy arrays (:func:`reconstruct`), and finished run
directories read back (:func:`load_run`)."""

from __future__ import annotations

import json
import shutil
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np

from . import _prism
from .arrays import check_array
from .geometry import Geometry

Progress = Union[None, bool, Callable[[str, Any, Any], None]]


@dataclass
class Run:
    """A finished run: its directory (``None`` when it was temporary), the volumes by channel
    label (``[z][y][x]`` float32, μ in mm⁻¹), the training log (``log.jsonl``: one dict per
    logged step, PSNR against time when the run had references), the scores (``metrics.json``)
    and the resolved config (YAML text)."""

    dir: Optional[Path]
    volumes: Dict[str, np.ndarray]
    log: List[dict] = field(default_factory=list)
    metrics: Optional[dict] = None
    config: str = ""


def load_run(directory: Union[str, Path]) -> Run:
    """The run ``prism recon`` (or :func:`reconstruct`) wrote in ``directory``."""
    d = Path(directory)
    manifest = d / "run.json"
    if not manifest.is_file():
        raise ValueError(f"{d}: not a run directory (no run.json)")
    files = json.loads(manifest.read_text()).get("files", [])
    volumes = {
        Path(f).stem: np.load(d / f)
        for f in files
        if f.endswith(".npy") and "/" not in f
    }
    log_file, metrics_file, config_file = d / "log.jsonl", d / "metrics.json", d / "config.resolved.yaml"
    log = [json.loads(line) for line in log_file.read_text().splitlines() if line.strip()] if log_file.is_file() else []
    metrics = json.loads(metrics_file.read_text()) if metrics_file.is_file() else None
    config = config_file.read_text() if config_file.is_file() else ""
    return Run(d, volumes, log, metrics, config)


def reconstruct(
    projections: np.ndarray,
    geometry: Geometry,
    method: Optional[str] = None,
    config: Union[None, str, Path, Mapping[str, Any]] = None,
    channels: Optional[Sequence[Any]] = None,
    availability: Optional[np.ndarray] = None,
    references: Optional[np.ndarray] = None,
    out: Union[None, str, Path] = None,
    force: bool = False,
    progress: Progress = None,
    allow_memory: bool = False,
) -> Run:
    """Reconstruct every channel with one of ``prism recon``'s methods (``fdk``, ``sart``,
    ``cgls``, ``tv``, ``naf``, ``r2gs``, ``4dsg-stage1``, ``4dsg``), through the same pipeline.

    * ``projections``: ``[channel][view][row][col]`` float32 line integrals (a 3-D array is one
      channel).
    * ``config``: a recon YAML file (``configs/recon/*.yaml``) or a dict of its fields;
      ``method`` alone takes that method's defaults, and overrides the config's ``method``.
    * ``channels``: one entry per channel: a number (a monoenergetic channel at that keV) or a
      dict ``{"label": …, "kind": "energy" | "tube_voltage" | "window" | "mixing", …}`` with the
      fields of a ``scene.yaml``'s channel coordinate (``kev``, ``kvp``, ``lo_kev``/``hi_kev``,
      ``lambda``/``low_kvp``/``high_kvp``). Optional for one channel.
    * ``availability``: ``[view][channel]`` bool, which channel was measured at which view
      (interleaved scans); all when omitted.
    * ``references``: ``[channel][z][y][x]`` volumes to score against (``Run.metrics``, and
      PSNR against time in ``Run.log``).
    * ``out``: the run directory to write (``force`` replaces an existing run); a temporary one,
      removed after reading, when omitted.
    * ``progress``: ``True`` shows tqdm bars (text lines without tqdm), or a callable
      ``f(kind, a, b)`` receives ``("phase", name, total)``, ``("progress", done, status)`` and
      ``("note", level, text)``.
    * ``allow_memory``: run even when the estimated peak memory exceeds what is available
      (otherwise a ``ValueError`` says how much the run needs, as ``prism recon`` does).

    Ctrl-C stops a training method at its next step and raises ``KeyboardInterrupt``."""
    p = projections[None] if isinstance(projections, np.ndarray) and projections.ndim == 3 else projections
    if not isinstance(p, np.ndarray) or p.ndim != 4:
        raise ValueError("projections: expected [channel][view][row][col] (or [view][row][col] for one channel)")
    check_array("projections[0]", p[0], geometry.projection_shape, "[view][row][col]")
    if not p.flags.c_contiguous:
        raise ValueError("projections: must be C-contiguous (numpy.ascontiguousarray(a) copies it so)")
    n = p.shape[0]
    chans = _channels(channels, n)
    if references is not None:
        if not (isinstance(references, np.ndarray) and references.ndim == 4 and references.shape[0] == n):
            raise ValueError(f"references: expected [channel][z][y][x] with {n} channels")
        check_array("references[0]", references[0], geometry.volume_shape, "[z][y][x]")
        references = np.ascontiguousarray(references)
    if availability is not None:
        availability = np.ascontiguousarray(availability, dtype=bool)
        if availability.shape != (geometry.views, n):
            raise ValueError(
                f"availability: shape {availability.shape} is not [view][channel] {(geometry.views, n)}"
            )
    text = _config_text(method, config)
    temporary = out is None
    target = Path(tempfile.mkdtemp(prefix="prism-run-")) / "run" if temporary else Path(out)
    callback, close = _progress(progress)
    try:
        published = _prism.reconstruct(
            p, geometry.to_json(), text, json.dumps(chans), str(target),
            availability, references, bool(force), callback, bool(allow_memory),
        )
        run = load_run(published)
    finally:
        close()
        if temporary:
            shutil.rmtree(target.parent, ignore_errors=True)
    if temporary:
        run.dir = None
    return run


def query(
    run: Union[Run, str, Path],
    kev: Optional[float] = None,
    coordinate: Optional[float] = None,
    tau: Optional[float] = None,
    projections: bool = False,
    extrapolate: bool = False,
) -> np.ndarray:
    """A trained spectral run (``4dsg``, ``4dsg-stage1``; a :class:`Run` or its directory) at
    exactly one point of its spectral axis, as ``prism query`` answers it, without further
    optimisation.

    * ``kev``: a virtual monoenergetic image at that photon energy: from the basis head when the
      run has one (any energy of the attenuation table; a warning outside the trained channels'
      energies), else the curves of a run whose channels are energies;
    * ``coordinate``: a point in the run's spectral unit (keV, kVp, λ, …);
    * ``tau``: the normalised coordinate (0 and 1 are the first and last channel).

    Returns the volume ``[z][y][x]`` (μ, mm⁻¹) or, with ``projections``, the line integrals
    ``[view][row][col]`` at every view of the run's geometry. ``extrapolate`` allows a
    coordinate outside the observed channels."""
    d = run.dir if isinstance(run, Run) else Path(run)
    if d is None:
        raise ValueError("query: the run was temporary; reconstruct(..., out=DIR) keeps its model")
    data, warning, _summary = _prism.query(
        str(d), coordinate, tau, kev, bool(projections), bool(extrapolate)
    )
    if warning:
        warnings.warn(warning, stacklevel=2)
    return data


def _channels(channels: Optional[Sequence[Any]], n: int) -> List[dict]:
    if channels is None:
        if n != 1:
            raise ValueError(f"channels: {n} channels need their spectral coordinates (e.g. [40, 70, 100] keV)")
        return [{"label": "channel", "coordinate": {"kind": "unspecified"}}]
    if len(channels) != n:
        raise ValueError(f"channels: {len(channels)} given for {n} channels of projections")
    out = []
    for i, c in enumerate(channels):
        if isinstance(c, Mapping):
            c = dict(c)
            label = c.pop("label", None)
            coordinate = c.pop("coordinate", c)
            if label is None:
                label = _label(coordinate, i)
            out.append({"label": str(label), "coordinate": coordinate})
        else:
            kev = float(c)
            out.append({"label": f"{kev:g}keV", "coordinate": {"kind": "energy", "kev": kev}})
    return out


def _label(coordinate: Mapping[str, Any], i: int) -> str:
    """A channel's default label from its coordinate (``140kVp``, ``60keV``, ``20-35keV``)."""
    kind = coordinate.get("kind")
    try:
        if kind == "energy":
            return f"{float(coordinate['kev']):g}keV"
        if kind == "tube_voltage":
            return f"{float(coordinate['kvp']):g}kVp"
        if kind == "window":
            return f"{float(coordinate['lo_kev']):g}-{float(coordinate['hi_kev']):g}keV"
        if kind == "mixing":
            return f"mix{float(coordinate['lambda']):g}"
    except (KeyError, TypeError, ValueError):
        pass  # the native side names the missing or bad field
    return f"channel{i}"


def _config_text(method: Optional[str], config: Union[None, str, Path, Mapping[str, Any]]) -> str:
    if config is None:
        if method is None:
            raise ValueError("reconstruct: give a method (e.g. method='r2gs') or a config")
        return json.dumps({"method": method})
    if isinstance(config, Mapping):
        fields = dict(config)
    else:
        path = Path(config)
        if not path.is_file():
            raise ValueError(f"config: {path} is not a file")
        if method is not None:
            raise ValueError("reconstruct: give config=<file> or method=, not both (the file names its method)")
        return path.read_text()
    if method is not None:
        fields["method"] = method
    return json.dumps(fields)


def _progress(progress: Progress):
    """The callback handed to the native side and what closes its display."""
    if progress is None or progress is False:
        return None, lambda: None
    if callable(progress):
        return progress, lambda: None
    try:
        from tqdm.auto import tqdm
    except ImportError:
        tqdm = None
    state: dict = {"bar": None}

    def close():
        if state["bar"] is not None:
            state["bar"].close()
            state["bar"] = None

    def show(kind, a, b):
        if kind == "phase":
            close()
            if tqdm is not None:
                state["bar"] = tqdm(total=b or None, desc=a, leave=True)
            else:
                print(f"{a} ({b} steps)" if b else a, flush=True)
        elif kind == "progress":
            bar = state["bar"]
            if bar is not None:
                bar.update(a - bar.n)
                if b:
                    bar.set_postfix_str(b, refresh=False)
        elif kind == "note":
            print(f"{a}: {b}", flush=True)

    return show, close
