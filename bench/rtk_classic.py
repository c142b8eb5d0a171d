#!/usr/bin/env python3
"""RTK side of Prism's classic-CT benchmark (called by `prism_recon::classic::bench`).

Usage: rtk_classic.py WORK_DIR [THREADS] [REPEATS]

WORK_DIR holds, written by the Rust benchmark in Prism's conventions (docs/geometry.md):
  geometry.json   Prism `Geometry` (cone beam; mm, radians)
  volume.npy      μ volume [z][y][x] float32 (the voxelised phantom, also the FDK reference)
  analytic.npy    exact line integrals [view][row][col] float32 (row 0 at the top, +z)

Prints one JSON object: Joseph forward projection time and its relative L2 error against the
analytic projections, FDK time and PSNR; times are the median of REPEATS runs with min and max (volumes divided by the reference's maximum, peak 1).
When RTK cannot be imported it prints {"available": false, "reason": ...} and exits 0.

Install: pip install itk-rtk   (CPU wheels; tested with itk-rtk 2.7.0.post1, itk 5.4.7)

Geometry mapping (checked by the FP error against the analytic projections, ~2 %, where a wrong
axis, sign or offset gives errors of order 100 %): RTK rotates about its y axis with the source at
R_y(θ)·(0, 0, SID). Prism's world (x, y, z) maps to RTK (X, Y, Z) = (y, z, x), a proper rotation,
under which Prism's source DSO·(cos θ, sin θ, 0) is RTK's source at gantry angle θ and Prism's
detector u axis (−sin θ, cos θ, 0) is RTK's u. RTK's v points to +z, Prism's rows run down, so
rows are flipped.
"""
import json
import sys
import time
from pathlib import Path

import numpy as np


def main():
    work = Path(sys.argv[1])
    threads = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    repeats = max(1, int(sys.argv[3])) if len(sys.argv) > 3 else 1
    try:
        import itk
        from itk import RTK as rtk
    except Exception as e:  # noqa: BLE001 - any import failure means "skip"
        print(json.dumps({"available": False, "reason": f"RTK not importable ({e}); pip install itk-rtk"}))
        return
    itk.MultiThreaderBase.SetGlobalDefaultNumberOfThreads(threads)
    g = json.loads((work / "geometry.json").read_text())
    if g["beam"] != "cone":
        print(json.dumps({"available": False, "reason": "the RTK comparison covers cone beam only"}))
        return
    vol = np.load(work / "volume.npy").astype(np.float32)
    analytic = np.load(work / "analytic.npy").astype(np.float32)
    d = g["detector"]
    n_views = len(g["angles_rad"])

    geometry, volume_image, projection_image = rtk_images(itk, rtk, g)
    image_type = itk.Image[itk.F, 3]

    # Joseph forward projection (fresh inputs per run: ITK pipelines may release their data).
    fp_times = []
    for _ in range(repeats):
        fp = rtk.JosephForwardProjectionImageFilter[image_type, image_type].New()
        fp.SetInput(0, projection_image(np.zeros((n_views, d["rows"], d["cols"]), np.float32)))
        fp.SetInput(1, volume_image(vol))
        fp.SetGeometry(geometry)
        t0 = time.perf_counter()
        fp.Update()
        fp_times.append(time.perf_counter() - t0)
    proj = itk.array_from_image(fp.GetOutput())[:, ::-1, :]
    fp_err = float(np.linalg.norm((proj - analytic).ravel()) / np.linalg.norm(analytic.ravel()))

    # FDK of the analytic projections (ramp filter, no Hann window, no truncation correction).
    fdk_times = []
    for _ in range(repeats):
        fdk = rtk.FDKConeBeamReconstructionFilter[image_type].New()
        fdk.SetInput(0, volume_image(np.zeros_like(vol)))
        fdk.SetInput(1, projection_image(analytic))
        fdk.SetGeometry(geometry)
        fdk.GetRampFilter().SetTruncationCorrection(0.0)
        fdk.GetRampFilter().SetHannCutFrequency(0.0)
        t0 = time.perf_counter()
        fdk.Update()
        fdk_times.append(time.perf_counter() - t0)
    rec = np.transpose(itk.array_from_image(fdk.GetOutput()), (1, 2, 0))
    peak = float(vol.max())
    mse = float(np.mean(((rec - vol) / peak).astype(np.float64) ** 2))
    print(json.dumps({
        "available": True,
        "version": getattr(itk, "__version__", "?"),
        "threads": threads,
        "timing": f"median of {repeats} (min, max in *_min_s, *_max_s)",
        "fp_s": float(np.median(fp_times)),
        "fp_min_s": min(fp_times),
        "fp_max_s": max(fp_times),
        "fp_rel_err_vs_analytic": fp_err,
        "fdk_s": float(np.median(fdk_times)),
        "fdk_min_s": min(fdk_times),
        "fdk_max_s": max(fdk_times),
        "fdk_psnr": 10 * np.log10(1.0 / mse),
    }))


def rtk_images(itk, rtk, g):
    """RTK's circular geometry for the Prism cone geometry `g` (its JSON fields), and the makers
    of RTK volume and projection images from Prism-ordered arrays (the mapping in the module
    docs). Also used by python/tests/test_prism.py."""
    d, v = g["detector"], g["volume"]
    geometry = rtk.ThreeDCircularProjectionGeometry.New()
    for a in g["angles_rad"]:
        geometry.AddProjection(g["dso"], g["dsd"], float(np.degrees(a)))
    centre0 = [v["offset"][k] + (0.5 - n / 2) * s for k, (n, s) in
               enumerate([(v["nx"], v["dx"]), (v["ny"], v["dy"]), (v["nz"], v["dz"])])]

    def volume_image(arr):
        # numpy [Z][Y][X] of RTK = Prism [x][z][y].
        img = itk.image_from_array(np.ascontiguousarray(np.transpose(arr, (2, 0, 1))))
        img.SetSpacing([v["dy"], v["dz"], v["dx"]])
        img.SetOrigin([centre0[1], centre0[2], centre0[0]])
        return img

    def projection_image(arr):
        img = itk.image_from_array(np.ascontiguousarray(arr[:, ::-1, :]))
        img.SetSpacing([d["pitch_u"], d["pitch_v"], 1.0])
        img.SetOrigin([(0.5 - d["cols"] / 2) * d["pitch_u"] + d.get("offset_u", 0.0),
                       (0.5 - d["rows"] / 2) * d["pitch_v"] - d.get("offset_v", 0.0), 0.0])
        return img

    return geometry, volume_image, projection_image


if __name__ == "__main__":
    main()
