"""Scan geometries in Prism's conventions (docs/geometry.md), built from keyword arguments, from
Prism's own ``geometry:`` fields (a ``scene.yaml``) or from TIGRE's ``geo`` fields."""

from __future__ import annotations

import json
import math
from typing import Any, Dict, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from . import _prism

Triple = Union[float, Sequence[float]]


def full_turn(views: int, start: float = 0.0) -> list:
    """``views`` angles (radians) evenly spaced over a full turn from ``start``, the endpoint
    excluded (``numpy.linspace(start, start + 2π, views + 1)[:-1]``)."""
    return [start + 2.0 * math.pi * i / views for i in range(views)]


def _zyx(name: str, value: Triple) -> Tuple[float, float, float]:
    """A per-axis value given once (all axes) or as ``(z, y, x)``."""
    if np.ndim(value) == 0:
        v = float(value)  # type: ignore[arg-type]
        return (v, v, v)
    values = tuple(float(v) for v in value)  # type: ignore[union-attr]
    if len(values) != 3:
        raise ValueError(f"{name}: expected one number or three (z, y, x), got {len(values)}")
    return values  # type: ignore[return-value]


class Geometry:
    """A complete scan: beam, distances, detector, volume grid and view angles.

    Lengths are mm, angles radians. The fields are those of a ``scene.yaml``'s ``geometry:``
    block (``beam``, ``dso``, ``dsd``, ``detector: {rows, cols, pitch_u, pitch_v, offset_u,
    offset_v}``, ``volume: {nx, ny, nz, dx, dy, dz, offset: [x, y, z]}``, ``angles_rad``); they
    are checked when the geometry is made, and an error names the field as the command line
    does."""

    def __init__(self, fields: Mapping[str, Any]):
        self._fields: Dict[str, Any] = json.loads(_prism.check_geometry(json.dumps(_plain(fields))))

    @classmethod
    def cone(
        cls,
        *,
        dso: float,
        dsd: float,
        rows: int,
        cols: int,
        pitch: Union[float, Tuple[float, float]],
        volume: Sequence[int],
        voxel: Triple,
        angles: Sequence[float],
        detector_offset: Tuple[float, float] = (0.0, 0.0),
        volume_offset: Triple = 0.0,
    ) -> "Geometry":
        """A circular cone-beam scan.

        ``dso``: source to rotation axis, ``dsd``: source to detector (mm). ``rows`` × ``cols``
        pixels of ``pitch`` mm (one number, or ``(row pitch v, column pitch u)``);
        ``detector_offset`` ``(u, v)`` shifts the detector centre within its plane (v points down
        the image). ``volume`` is the array shape ``(nz, ny, nx)``; ``voxel`` and
        ``volume_offset`` (the grid centre against the isocentre) are one number or ``(z, y,
        x)``. ``angles``: radians, one per view."""
        return cls(
            _fields("cone", dso, dsd, rows, cols, pitch, volume, voxel, angles, detector_offset, volume_offset)
        )

    @classmethod
    def parallel(
        cls,
        *,
        rows: int,
        cols: int,
        pitch: Union[float, Tuple[float, float]],
        volume: Sequence[int],
        voxel: Triple,
        angles: Sequence[float],
        detector_offset: Tuple[float, float] = (0.0, 0.0),
        volume_offset: Triple = 0.0,
    ) -> "Geometry":
        """A parallel-beam scan (synchrotron, or a fan-free approximation): rays along
        ``(−cos θ, −sin θ, 0)``. The other arguments are :meth:`cone`'s. The rays start on a plane
        twice the volume's reach before the axis, and the detector lies as far beyond it."""
        _, dy, dx = _zyx("voxel", voxel)
        _, ny, nx = (int(n) for n in volume)
        _, oy, ox = _zyx("volume_offset", volume_offset)
        reach = math.hypot(abs(ox) + nx * dx / 2, abs(oy) + ny * dy / 2)
        dso = 2.0 * max(reach, 1e-3)
        return cls(
            _fields(
                "parallel", dso, 2.0 * dso, rows, cols, pitch, volume, voxel, angles, detector_offset, volume_offset
            )
        )

    @classmethod
    def from_tigre(cls, geo: Any, angles: Sequence[float]) -> "Geometry":
        """The geometry a TIGRE ``geo`` describes (a ``tigre.geometry`` object or a dict with its
        fields), with ``angles`` in radians as TIGRE takes them.

        Field mapping (TIGRE's orders are ``(z, y, x)`` and ``(v, u)``): ``DSO`` → ``dso``,
        ``DSD`` → ``dsd``, ``nDetector`` → ``(rows, cols)``, ``dDetector`` → ``(pitch_v,
        pitch_u)``, ``offDetector`` → ``(−offset_v, offset_u)`` (TIGRE's v points up),
        ``nVoxel``/``dVoxel``/``offOrigin`` → the volume's ``(nz, ny, nx)``, ``(dz, dy, dx)``,
        ``(z, y, x)`` offset, ``mode`` → ``beam``. ``sVoxel`` and ``sDetector``, when present,
        must equal ``nVoxel·dVoxel`` and ``nDetector·dDetector``. TIGRE's projection row 0 is
        the lowest z: convert its arrays with :func:`tigre_projections`."""
        keys = ("mode", "DSD", "DSO", "nDetector", "dDetector", "offDetector", "nVoxel", "dVoxel", "offOrigin")
        get = geo.get if isinstance(geo, Mapping) else (lambda k, d=None: getattr(geo, k, d))
        fields = {k: _plain(get(k)) for k in keys if get(k) is not None}
        for total, count, step in (("sVoxel", "nVoxel", "dVoxel"), ("sDetector", "nDetector", "dDetector")):
            size = get(total)
            if size is not None and count in fields and step in fields:
                want = np.asarray(fields[count], float) * np.asarray(fields[step], float)
                if not np.allclose(np.asarray(_plain(size), float), want, rtol=1e-6, atol=0.0):
                    raise ValueError(
                        f"TIGRE geometry: {total} {list(np.asarray(_plain(size), float))} is not "
                        f"{count} × {step} {list(want)}"
                    )
        angles = [float(a) for a in np.asarray(angles, float).ravel()]
        return cls(json.loads(_prism.geometry_from_tigre(json.dumps(fields), angles)))

    @classmethod
    def fan(
        cls,
        *,
        dso: float,
        dsd: float,
        cols: int,
        pitch: float,
        slice: Sequence[int],
        voxel: Union[float, Sequence[float]],
        angles: Sequence[float],
        detector_offset: float = 0.0,
        slice_offset: Sequence[float] = (0.0, 0.0),
    ) -> "Geometry":
        """A 2-D fan beam on a flat detector line (``cols`` pixels of ``pitch`` mm, shifted
        ``detector_offset`` mm along u), reconstructing one slice of shape ``slice`` ``(ny,
        nx)`` with ``voxel`` one number or ``(dy, dx)`` and centre ``slice_offset`` ``(y, x)``.

        Stored as Prism stores fans (docs/geometry.md): the middle row of a cone beam, one
        detector row over a one-voxel-thick volume. Volumes are ``[1][y][x]``, projections
        ``[view][1][col]``."""
        ny, nx = (int(n) for n in slice)
        dy, dx = (float(voxel),) * 2 if np.ndim(voxel) == 0 else (float(v) for v in voxel)  # type: ignore[arg-type]
        oy, ox = (float(o) for o in slice_offset)
        fields = {
            "dso": float(dso), "dsd": float(dsd), "cols": int(cols), "pitch": float(pitch),
            "offset_u": float(detector_offset), "nx": nx, "ny": ny, "dx": dx, "dy": dy, "offset": [ox, oy],
        }
        angles = [float(a) for a in np.asarray(angles, float).ravel()]
        return cls(json.loads(_prism.geometry_from_fan(json.dumps(fields), angles)))

    @classmethod
    def from_vectors(
        cls,
        beam: str,
        vectors: Any,
        *,
        cols: int,
        volume: Sequence[int],
        voxel: Triple,
        rows: Optional[int] = None,
        volume_offset: Triple = 0.0,
        angles: Optional[Sequence[float]] = None,
    ) -> "Geometry":
        """Every view placed by a row of ASTRA's vectors (docs/geometry.md, "Per-view
        vectors"): ``beam`` ``cone`` or ``parallel`` with 12 numbers per view (``cone_vec``,
        ``parallel3d_vec``: source or ray, detector centre, u, v; v one row step, row 0 first)
        on ``rows`` × ``cols`` pixels, or ``fan`` with 6 (``fanflat_vec``: source, detector
        centre, u, in the plane z = 0) on one row and a one-voxel-thick ``volume``. ``volume``,
        ``voxel`` and ``volume_offset`` are :meth:`cone`'s; ``angles`` (the nominal view angles)
        are derived from the vectors when omitted."""
        rows_of = np.asarray(vectors, dtype=float)
        if rows_of.ndim != 2:
            raise ValueError(f"vectors: expected [views, 12] or [views, 6], got shape {rows_of.shape}")
        spec = {"beam": beam, "cols": int(cols), "volume": _volume(volume, voxel, volume_offset)}
        if rows is not None:
            spec["rows"] = int(rows)
        if angles is not None:
            angles = [float(a) for a in np.asarray(angles, float).ravel()]
        return cls(json.loads(_prism.geometry_from_vectors(json.dumps(spec), rows_of.tolist(), angles)))

    @classmethod
    def from_astra(cls, proj_geom: Mapping[str, Any], vol_geom: Mapping[str, Any]) -> "Geometry":
        """The geometry of an ASTRA scan: ``proj_geom`` (``astra.create_proj_geom``) of type
        ``fanflat`` or ``fanflat_vec`` with a 2-D ``vol_geom``, or ``cone``, ``cone_vec``,
        ``parallel3d`` or ``parallel3d_vec`` with a 3-D one (``astra.create_vol_geom``), lengths
        in mm (ASTRA's unit is whatever the two share).

        2-D, checked against ASTRA's CPU projector (``strip_fanflat``, tested): at angle θ a
        ``fanflat`` source sits at ``DSO·(sin θ, −cos θ)``, the detector centre at ``ODD·(−sin θ,
        cos θ)``, column steps along ``w·(cos θ, sin θ)`` (as ``astra.geom_2vec`` writes them);
        an image's row 0 is the *largest* y. Convert arrays with :func:`astra_image` and
        :func:`astra_sinogram`.

        3-D, from ASTRA's CUDA kernels (its only 3-D projectors; no GPU checked them here): a
        ``cone`` source at ``DSO·(sin θ, −cos θ, 0)``, detector centre ``ODD·(−sin θ, cos θ, 0)``,
        ``u = DetectorSpacingX·(cos θ, sin θ, 0)``, ``v = (0, 0, DetectorSpacingY)``;
        ``parallel3d`` the same with rays along ``(−sin θ, cos θ, 0)`` and the detector centre at
        the origin. Volumes ``[slice][row][col]`` are Prism's ``[z][y][x]`` as they are (in 3-D
        ASTRA's row 0 is the *smallest* y, unlike its 2-D images); projections ``[row][angle][col]``
        have row 0 at the lowest z, Prism's at the highest: convert with :func:`astra_volume` and
        :func:`astra_projections`. The detector is therefore taken with its rows reversed (``v``
        negated), so a ``*_vec`` geometry whose ``u × v`` does not point towards the source (as
        ASTRA's own conversions' do) is refused as a mirrored image."""
        kind = proj_geom.get("type")
        if kind in ("cone", "cone_vec", "parallel3d", "parallel3d_vec"):
            return cls._from_astra_3d(proj_geom, vol_geom)
        if kind == "fanflat":
            angles = np.asarray(proj_geom["ProjectionAngles"], float).ravel()
            dso = float(proj_geom["DistanceOriginSource"])
            odd = float(proj_geom["DistanceOriginDetector"])
            w = float(proj_geom["DetectorWidth"])
            s, c = np.sin(angles), np.cos(angles)
            vectors = np.stack([dso * s, -dso * c, -odd * s, odd * c, w * c, w * s], axis=1)
            cols = int(proj_geom["DetectorCount"])
        elif kind == "fanflat_vec":
            vectors = np.asarray(proj_geom["Vectors"], float)
            cols = int(proj_geom["DetectorCount"])
        else:
            raise ValueError(
                f"from_astra: proj_geom type {kind!r} is not mapped: fanflat, fanflat_vec, cone, "
                "cone_vec, parallel3d and parallel3d_vec are"
            )
        if "GridSliceCount" in vol_geom:
            raise ValueError(f"from_astra: a {kind} geometry needs a 2-D vol_geom; this one has GridSliceCount")
        opt = vol_geom.get("option", vol_geom)
        ny, nx = int(vol_geom["GridRowCount"]), int(vol_geom["GridColCount"])
        x0, x1 = float(opt["WindowMinX"]), float(opt["WindowMaxX"])
        y0, y1 = float(opt["WindowMinY"]), float(opt["WindowMaxY"])
        dx, dy = (x1 - x0) / nx, (y1 - y0) / ny
        # The slice as thick as a column seen at the axis (no ray leaves z = 0, so any thickness
        # gives the same line integrals), as Prism's own fan geometry.
        src, det = vectors[0, 0:2], vectors[0, 2:4]
        pitch = float(np.hypot(*vectors[0, 4:6]))
        dz = pitch * float(np.hypot(*src)) / float(np.hypot(*(det - src)))
        return cls.from_vectors(
            "fan", vectors, cols=cols, volume=(1, ny, nx), voxel=(dz, dy, dx),
            volume_offset=(0.0, (y0 + y1) / 2, (x0 + x1) / 2),
        )

    @classmethod
    def _from_astra_3d(cls, proj_geom: Mapping[str, Any], vol_geom: Mapping[str, Any]) -> "Geometry":
        kind = str(proj_geom["type"])
        cone = kind.startswith("cone")
        rows, cols = int(proj_geom["DetectorRowCount"]), int(proj_geom["DetectorColCount"])
        if kind.endswith("_vec"):
            vectors = np.array(proj_geom["Vectors"], dtype=float, ndmin=2)
            if vectors.ndim != 2 or vectors.shape[1] != 12:
                raise ValueError(f"from_astra: {kind} Vectors must be [views, 12], got shape {vectors.shape}")
        else:
            angles = np.asarray(proj_geom["ProjectionAngles"], float).ravel()
            s, c, o = np.sin(angles), np.cos(angles), np.zeros_like(angles)
            du, dv = float(proj_geom["DetectorSpacingX"]), float(proj_geom["DetectorSpacingY"])
            if cone:
                dso = float(proj_geom["DistanceOriginSource"])
                odd = float(proj_geom["DistanceOriginDetector"])
                src, det = [dso * s, -dso * c, o], [-odd * s, odd * c, o]
            else:
                src, det = [-s, c, o], [o, o, o]
            vectors = np.stack(src + det + [du * c, du * s, o, o, o, dv + o], axis=1)
        # ASTRA's detector row r is Prism's row rows − 1 − r: the same pixel centres with v negated.
        vectors[:, 9:12] *= -1.0
        if "GridSliceCount" not in vol_geom:
            raise ValueError(f"from_astra: a {kind} geometry needs a 3-D vol_geom (GridSliceCount missing)")
        opt = vol_geom.get("option", vol_geom)
        nz, ny, nx = (int(vol_geom[k]) for k in ("GridSliceCount", "GridRowCount", "GridColCount"))
        lo = np.array([float(opt[f"WindowMin{a}"]) for a in "ZYX"])
        hi = np.array([float(opt[f"WindowMax{a}"]) for a in "ZYX"])
        voxel = tuple((hi - lo) / np.array([nz, ny, nx]))
        centre = tuple((lo + hi) / 2)
        if not cone:
            # A parallel ray's sign changes no line integral; Prism reads the detector from the
            # side the rays arrive at, so they travel along u × v.
            normal = np.cross(vectors[:, 6:9], vectors[:, 9:12])
            sign = np.sign(np.sum(normal * vectors[:, 0:3], axis=1))
            vectors[:, 0:3] *= np.where(sign == 0, 1.0, sign)[:, None]
            # Nor does sliding the detector along the rays; ASTRA's passes through the origin,
            # Prism's must lie beyond the volume.
            ray = vectors[:, 0:3] / np.linalg.norm(vectors[:, 0:3], axis=1, keepdims=True)
            reach = float(np.linalg.norm(centre) + np.linalg.norm(hi - lo) / 2) + 1.0
            depth = np.sum(vectors[:, 3:6] * ray, axis=1)
            vectors[:, 3:6] += np.maximum(reach - depth, 0.0)[:, None] * ray
        return cls.from_vectors(
            "cone" if cone else "parallel", vectors, rows=rows, cols=cols, volume=(nz, ny, nx),
            voxel=voxel, volume_offset=centre,
        )

    def to_tigre(self) -> Dict[str, Any]:
        """TIGRE's ``geo`` fields for this geometry (the inverse of :meth:`from_tigre`; angles
        are :attr:`angles`). Circular scans only."""
        if self._fields.get("vectors") is not None:
            raise ValueError("to_tigre: a geometry with per-view vectors has no TIGRE form")
        d, v = self._fields["detector"], self._fields["volume"]
        n_det = [d["rows"], d["cols"]]
        d_det = [d["pitch_v"], d["pitch_u"]]
        n_vox = [v["nz"], v["ny"], v["nx"]]
        d_vox = [v["dz"], v["dy"], v["dx"]]
        return {
            "mode": self._fields["beam"],
            "DSO": self._fields["dso"],
            "DSD": self._fields["dsd"],
            "nDetector": n_det,
            "dDetector": d_det,
            "sDetector": [n * s for n, s in zip(n_det, d_det)],
            "offDetector": [-d.get("offset_v", 0.0), d.get("offset_u", 0.0)],
            "nVoxel": n_vox,
            "dVoxel": d_vox,
            "sVoxel": [n * s for n, s in zip(n_vox, d_vox)],
            "offOrigin": list(reversed(v.get("offset", [0.0, 0.0, 0.0]))),
        }

    def to_dict(self) -> Dict[str, Any]:
        """The geometry's fields (a copy), as a ``scene.yaml``'s ``geometry:`` block holds them."""
        return json.loads(json.dumps(self._fields))

    def to_json(self) -> str:
        """The fields as JSON (what the native module reads)."""
        return json.dumps(self._fields)

    @property
    def beam(self) -> str:
        """``cone`` or ``parallel``."""
        return self._fields["beam"]

    @property
    def angles(self) -> list:
        """View angles, radians."""
        return list(self._fields["angles_rad"])

    @property
    def views(self) -> int:
        return len(self._fields["angles_rad"])

    @property
    def volume_shape(self) -> Tuple[int, int, int]:
        """``(nz, ny, nx)``: the shape of a volume array."""
        v = self._fields["volume"]
        return (v["nz"], v["ny"], v["nx"])

    @property
    def projection_shape(self) -> Tuple[int, int, int]:
        """``(views, rows, cols)``: the shape of a projection array."""
        d = self._fields["detector"]
        return (self.views, d["rows"], d["cols"])

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Geometry) and self._fields == other._fields

    def __repr__(self) -> str:
        return (
            f"Geometry({self.beam}, {self.views} views, detector {self.projection_shape[1:]}, "
            f"volume {self.volume_shape})"
        )


def astra_image(image: np.ndarray) -> np.ndarray:
    """An ASTRA 2-D image ``[row][col]`` (row 0 the largest y) as a Prism fan volume
    ``[1][y][x]`` (y increasing), float32 and C-contiguous."""
    return np.ascontiguousarray(np.asarray(image)[None, ::-1, :], dtype=np.float32)


def to_astra_image(volume: np.ndarray) -> np.ndarray:
    """The inverse of :func:`astra_image`: a Prism fan volume ``[1][y][x]`` as ASTRA's
    ``[row][col]``."""
    return np.ascontiguousarray(np.asarray(volume)[0, ::-1, :], dtype=np.float32)


def astra_volume(volume: np.ndarray) -> np.ndarray:
    """An ASTRA 3-D volume ``[slice][row][col]`` as a Prism volume ``[z][y][x]``: the same axes
    in the same order (ASTRA's 3-D row 0 is the smallest y, slice 0 the smallest z), float32 and
    C-contiguous. Its own inverse."""
    a = np.asarray(volume)
    if a.ndim != 3:
        raise ValueError(f"astra_volume: expected a 3-D volume [slice][row][col], got shape {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float32)


def astra_projections(projections: np.ndarray) -> np.ndarray:
    """ASTRA 3-D projections ``[row][angle][col]`` (row 0 the lowest z) as Prism's
    ``[view][row][col]`` (row 0 the highest z), float32 and C-contiguous."""
    a = np.asarray(projections)
    if a.ndim != 3:
        raise ValueError(f"astra_projections: expected [row][angle][col], got shape {a.shape}")
    return np.ascontiguousarray(a.transpose(1, 0, 2)[:, ::-1, :], dtype=np.float32)


def to_astra_projections(projections: np.ndarray) -> np.ndarray:
    """The inverse of :func:`astra_projections`: Prism's ``[view][row][col]`` as ASTRA's
    ``[row][angle][col]``."""
    a = np.asarray(projections)
    if a.ndim != 3:
        raise ValueError(f"to_astra_projections: expected [view][row][col], got shape {a.shape}")
    return np.ascontiguousarray(a[:, ::-1, :].transpose(1, 0, 2), dtype=np.float32)


def astra_sinogram(sinogram: np.ndarray) -> np.ndarray:
    """An ASTRA 2-D sinogram ``[angle][detector]`` as Prism fan projections ``[view][1][col]``
    (the same column order)."""
    return np.ascontiguousarray(np.asarray(sinogram)[:, None, :], dtype=np.float32)


def tigre_projections(projections: np.ndarray) -> np.ndarray:
    """TIGRE's projections ``[angle][v][u]`` (row 0 the lowest z) in Prism's orientation (row 0
    the highest z), float32 and C-contiguous; the map is its own inverse."""
    return np.ascontiguousarray(np.asarray(projections)[:, ::-1, :], dtype=np.float32)


def _fields(
    beam: str,
    dso: float,
    dsd: float,
    rows: int,
    cols: int,
    pitch: Union[float, Tuple[float, float]],
    volume: Sequence[int],
    voxel: Triple,
    angles: Sequence[float],
    detector_offset: Tuple[float, float],
    volume_offset: Triple,
) -> Dict[str, Any]:
    if np.ndim(pitch) == 0:
        pitch_v = pitch_u = float(pitch)  # type: ignore[arg-type]
    else:
        pitch_v, pitch_u = (float(p) for p in pitch)  # type: ignore[union-attr]
    return {
        "beam": beam,
        "dso": float(dso),
        "dsd": float(dsd),
        "detector": {
            "rows": int(rows),
            "cols": int(cols),
            "pitch_u": pitch_u,
            "pitch_v": pitch_v,
            "offset_u": float(detector_offset[0]),
            "offset_v": float(detector_offset[1]),
        },
        "volume": _volume(volume, voxel, volume_offset),
        "angles_rad": [float(a) for a in np.asarray(angles, float).ravel()],
    }


def _volume(volume: Sequence[int], voxel: Triple, offset: Triple) -> Dict[str, Any]:
    """Prism's `volume` fields for an array shape ``(nz, ny, nx)``, voxel sizes and a grid centre
    (each one number or ``(z, y, x)``)."""
    shape = [int(n) for n in volume]
    if len(shape) != 3:
        raise ValueError(f"volume: expected the array shape (nz, ny, nx), got {tuple(volume)}")
    dz, dy, dx = _zyx("voxel", voxel)
    oz, oy, ox = _zyx("volume_offset", offset)
    return {"nx": shape[2], "ny": shape[1], "nz": shape[0], "dx": dx, "dy": dy, "dz": dz, "offset": [ox, oy, oz]}


def _plain(value: Any) -> Any:
    """NumPy scalars and arrays (TIGRE stores its fields so) as plain Python numbers and lists."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
