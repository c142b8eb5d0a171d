#!/usr/bin/env python3
"""Hostile-input sweep of the `prism` binary: several hundred malformed or hostile inputs across
every command, each run in a directory of its own, each outcome classified.

    python3 scripts/hostile-sweep.py [--prism target/release/prism] [--work DIR] [--only TEXT]
                                     [--timeout 60] [--json report.json]

Before the cases, the script builds what they corrupt with the binary itself: a tiny simulated
two-channel scene, FDK, R²-Gaussian, 4D-SG (curve and basis head) and NAF runs, an import
(line integrals, counts with a TIFF flat field), and resume files of interrupted runs (SIGINT).
Every case then copies what it needs into its own directory, beside a file of the user's
(`mine.txt`; the cases about outputs also put one in the output directory), and runs one
command.

Outcomes (each case states what it expects: `error`, `ok`, or `any` where either is right):
* `crash`: a panic (exit status 101, or "panicked at"), or a signal other than SIGABRT;
* `abort`: SIGABRT, or Rust's "memory allocation of … failed";
* `killed`: SIGKILL (the kernel's OOM killer);
* `hang`: still running after the timeout;
* `silent success`: exit status 0 where an error was expected;
* `unclear error`: a failure whose message does not start with `error:`;
* `false refusal`: an error where success was expected;
* `lost file`: a file present before the command (the user's `mine.txt`, inputs) changed or gone,
  unless the case says the command replaces it;
* `clean`: everything else. The script exits 1 when any case is not clean.
"""

import argparse
import hashlib
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# ---------------------------------------------------------------------------------------------
# File writers (independent of Prism's own)


def npy(path, descr, shape, data=b"", fortran=False, version=1, header_extra=""):
    """A .npy file with the given header fields and raw data bytes."""
    shape_text = "(" + ", ".join(str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
    d = "{'descr': '%s', 'fortran_order': %s, 'shape': %s, %s}" % (
        descr, "True" if fortran else "False", shape_text, header_extra)
    pre = 10 if version == 1 else 12
    while (pre + len(d) + 1) % 64:
        d += " "
    d += "\n"
    out = b"\x93NUMPY" + bytes([version, 0])
    out += struct.pack("<H", len(d)) if version == 1 else struct.pack("<I", len(d))
    with open(path, "wb") as f:
        f.write(out + d.encode() + data)


def f32(values):
    return struct.pack("<%df" % len(values), *values)


def tiff(path, pages, width, height, bits=16, compression=1, strip=None, sample_format=1):
    """A little-endian TIFF of `pages` grayscale pages (zeros unless `strip` gives the bytes)."""
    bpp = bits // 8
    out = bytearray(b"II*\0" + struct.pack("<I", 0))
    offsets = []
    for _ in range(pages):
        data = strip if strip is not None else bytes(width * height * bpp)
        offsets.append(len(out))
        out += data
    ifd_pos = []
    for p in range(pages):
        if len(out) % 2:
            out += b"\0"
        ifd_pos.append(len(out))
        data_len = len(strip) if strip is not None else width * height * bpp
        entries = [(256, 4, width), (257, 4, height), (258, 3, bits), (259, 3, compression),
                   (262, 3, 1), (273, 4, offsets[p]), (277, 3, 1), (278, 4, height),
                   (279, 4, data_len), (339, 3, sample_format)]
        out += struct.pack("<H", len(entries))
        for tag, kind, value in entries:
            if kind == 3:
                out += struct.pack("<HHIHH", tag, kind, 1, value, 0)
            else:
                out += struct.pack("<HHII", tag, kind, 1, value)
        out += struct.pack("<I", 0)
    # Chain the IFDs.
    struct.pack_into("<I", out, 4, ifd_pos[0])
    for a, b in zip(ifd_pos, ifd_pos[1:]):
        n = struct.unpack_from("<H", out, a)[0]
        struct.pack_into("<I", out, a + 2 + 12 * n, b)
    with open(path, "wb") as f:
        f.write(bytes(out))


def st_read(path):
    b = open(path, "rb").read()
    n = struct.unpack("<Q", b[:8])[0]
    return json.loads(b[8:8 + n]), b[8 + n:]


def st_write(path, header, data):
    h = json.dumps(header).encode()
    h += b" " * ((8 - len(h) % 8) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(h)) + h + data)


def st_edit_meta(path, key, edit):
    """Edit the JSON metadata entry `key` of a safetensors file in place: `edit(value)` returns
    the new value (a string is stored as is, anything else as JSON)."""
    header, data = st_read(path)
    meta = header["__metadata__"]
    try:
        value = json.loads(meta[key])
    except (json.JSONDecodeError, KeyError):
        value = meta.get(key)
    new = edit(value)
    meta[key] = new if isinstance(new, str) else json.dumps(new)
    st_write(path, header, data)


def st_edit_tensor_shape(path, name, shape):
    header, data = st_read(path)
    header[name]["shape"] = shape
    st_write(path, header, data)


def yaml_value(v):
    """A YAML literal: RAW:text is written as is."""
    if isinstance(v, str) and v.startswith("RAW:"):
        return v[4:]
    return json.dumps(v)


def set_path(d, dotted, value):
    keys = dotted.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if isinstance(d, list) else d.setdefault(k, {})
    last = keys[-1]
    if isinstance(d, list):
        d[int(last)] = value
    else:
        d[last] = value


def dump_yaml(obj):
    """JSON with RAW: values spliced in as YAML tokens (YAML is a superset of JSON)."""
    text = json.dumps(obj)
    for token in set(_raw_tokens(obj)):
        text = text.replace(json.dumps("RAW:" + token), token)
    return text + "\n"


def _raw_tokens(obj):
    if isinstance(obj, dict):
        for v in obj.values():
            yield from _raw_tokens(v)
    elif isinstance(obj, list):
        for v in obj:
            yield from _raw_tokens(v)
    elif isinstance(obj, str) and obj.startswith("RAW:"):
        yield obj[4:]


# ---------------------------------------------------------------------------------------------
# Base artefacts

SCENE = {
    "name": "sweep",
    "geometry": {"beam": "cone", "dso": 1000.0, "dsd": 1500.0,
                 "detector": {"rows": 12, "cols": 12, "size_mm": [512.0, 512.0]},
                 "volume": {"n": 12, "size_mm": 256.0}, "views": 8, "test_views": 2},
    "object": {"phantom": {"radius_mm": 110.0}},
    "channels": [{"kind": "mono", "kev": 40}, {"kind": "mono", "kev": 70}],
}

METHODS = {
    "fdk": {"method": "fdk"},
    "sart": {"method": "sart", "iterations": 2},
    "cgls": {"method": "cgls", "iterations": 3},
    "tv": {"method": "tv", "iterations": 5},
    "r2gs": {"method": "r2gs", "iterations": 30, "init": {"n_points": 200}, "eval_every": 0},
    "4dsg": {"method": "4dsg", "iterations": 30, "init": {"n_points": 200}, "eval_every": 0,
             "stage2": {"iterations": 10, "curve_model": {"width": 8, "depth": 1}}},
    "basis": {"method": "4dsg", "iterations": 30, "init": {"n_points": 200}, "eval_every": 0,
              "stage2": {"iterations": 10, "basis": {"materials": ["water", "cortical_bone"]},
                         "freeze": {"position": False, "rotation": False, "scale": False,
                                    "density": False}}},
    "naf": {"method": "naf", "iterations": 30, "rays_per_batch": 64, "samples_per_ray": 12,
            "eval_every": 100, "field": {"width": 8, "hash_grid": {
                "levels": 3, "base_resolution": 4, "growth": 2.0, "log2_table_size": 8}}},
}

IMPORT = {
    "name": "imported",
    "geometry": {"prism": {"beam": "cone", "dso": 1000.0, "dsd": 1500.0,
                           "detector": {"rows": 12, "cols": 12, "pitch_u": 40.0, "pitch_v": 40.0,
                                        "offset_u": 0.0, "offset_v": 0.0},
                           "volume": {"nx": 12, "ny": 12, "nz": 12, "dx": 20.0, "dy": 20.0,
                                      "dz": 20.0, "offset": [0.0, 0.0, 0.0]}}},
    "angles": {"count": 16},
    "channels": [{"label": "a", "coordinate": {"kind": "energy", "kev": 60.0},
                  "line_integrals": {"path": "p.npy"}}],
    "select": {"views": 8, "test_views": 2, "reference": "none"},
}


class Base:
    def __init__(self, prism, root):
        self.prism, self.root = prism, root
        os.makedirs(root, exist_ok=True)

    def run(self, *args, ok=True):
        r = subprocess.run([self.prism, *args], cwd=self.root, capture_output=True, text=True)
        if ok and r.returncode != 0:
            sys.exit("setting up failed: prism %s\n%s%s" % (" ".join(args), r.stdout, r.stderr))
        return r

    def build(self):
        with open(os.path.join(self.root, "scene.yaml"), "w") as f:
            f.write(dump_yaml(SCENE))
        self.run("simulate", "scene.yaml", "-o", "scene")
        for name, cfg in METHODS.items():
            with open(os.path.join(self.root, name + ".yaml"), "w") as f:
                f.write(dump_yaml(cfg))
            if name in ("sart", "cgls", "tv"):
                continue
            self.run("recon", name + ".yaml", "-s", "scene", "-o", "run-" + name)
        # Import inputs.
        imp = os.path.join(self.root, "import")
        os.makedirs(imp, exist_ok=True)
        npy(os.path.join(imp, "p.npy"), "<f4", (16, 12, 12), f32([0.1] * (16 * 144)))
        counts = struct.pack("<%dH" % (16 * 144), *([3000] * (16 * 144)))
        npy(os.path.join(imp, "counts.npy"), "<u2", (16, 12, 12), counts)
        tiff(os.path.join(imp, "flat.tif"), 2, 12, 12,
             strip=struct.pack("<144H", *([10000] * 144)))
        with open(os.path.join(imp, "import.yaml"), "w") as f:
            f.write(dump_yaml(IMPORT))
        self.run("import", "import/import.yaml", "-o", "imported")
        # Resume files: interrupted runs (SIGINT once training has started).
        for name, cfg in [("r2gs", dict(METHODS["r2gs"], iterations=4000)),
                          ("naf", dict(METHODS["naf"], iterations=40000))]:
            path = os.path.join(self.root, "long-%s.yaml" % name)
            with open(path, "w") as f:
                f.write(dump_yaml(cfg))
            ckpt = os.path.join(self.root, "stopped-%s.ckpt" % name)
            p = subprocess.Popen([self.prism, "recon", path, "-s", "scene", "-o",
                                  "stopped-" + name, "--checkpoint", ckpt], cwd=self.root,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(3.0)
            p.send_signal(signal.SIGINT)
            p.wait(timeout=120)
            if not os.path.isfile(ckpt):
                sys.exit("setting up failed: no checkpoint from the interrupted %s run" % name)
        # A suite of one FDK cell.
        suite = {"name": "s", "scenes": {"a": {"config": "scene.yaml"}},
                 "methods": {"fdk": {"config": "fdk.yaml"}},
                 "studies": [{"name": "t", "kind": "table", "methods": ["fdk"], "scenes": ["a"]}]}
        with open(os.path.join(self.root, "suite.yaml"), "w") as f:
            f.write(dump_yaml(suite))


# ---------------------------------------------------------------------------------------------
# Cases


class Case:
    def __init__(self, name, args, expect="error", setup=None, replaces=(), outputs=()):
        self.name, self.args, self.expect = name, args, expect
        self.setup, self.replaces, self.outputs = setup, set(replaces), outputs


def cases():
    out = []

    def add(*a, **k):
        out.append(Case(*a, **k))

    bad_numbers = ["RAW:-1", "RAW:0", "RAW:.nan", "RAW:.inf", "RAW:-.inf", "RAW:1e308",
                   "text", "RAW:[]", "RAW:{}", "RAW:null", "RAW:18446744073709551616"]

    # --- simulate: scene configs with one field made hostile.
    fields = {
        "geometry.dso": bad_numbers,
        "geometry.dsd": bad_numbers + ["RAW:500"],
        "geometry.detector.rows": bad_numbers + ["RAW:1000000000000", "RAW:4294967296"],
        "geometry.detector.cols": ["RAW:0", "RAW:-3", "RAW:1000000000000", "RAW:1.5"],
        "geometry.detector.size_mm": ["RAW:[0, 0]", "RAW:[-1, 1]", "RAW:[.nan, 1]", "RAW:[1]",
                                      "RAW:[1e308, 1e308]"],
        "geometry.volume.n": ["RAW:0", "RAW:-1", "RAW:100000", "RAW:.nan", "RAW:1e12"],
        "geometry.volume.size_mm": ["RAW:0", "RAW:-1", "RAW:.nan", "RAW:.inf", "RAW:1e308"],
        "geometry.views": ["RAW:0", "RAW:-1", "RAW:1000000000000", "RAW:1e308"],
        "geometry.test_views": ["RAW:-1", "RAW:1000000000000"],
        "geometry.beam": ["fan3d", "RAW:1", ""],
        "object.phantom.radius_mm": ["RAW:-1", "RAW:.nan", "RAW:0", "RAW:1e308"],
        "channels": ["RAW:[]", "text", "RAW:[{kind: mono, kev: -1}]",
                     "RAW:[{kind: mono, kev: .nan}]", "RAW:[{kind: mono, kev: 1e6}]",
                     "RAW:[{kind: mono, kev: 40}, {kind: mono, kev: 40}]",
                     "RAW:[{kind: nope}]", "RAW:[{kind: mono}]"],
        "noise": ["RAW:{i0: -1}", "RAW:{i0: 0}", "RAW:{i0: .nan}", "RAW:{i0: .inf}"],
        "name": ["RAW:[]", "RAW:\"a\\nb\""],
    }
    for field, values in fields.items():
        for i, v in enumerate(values):
            cfg = json.loads(json.dumps(SCENE))
            set_path(cfg, field, v)
            text = dump_yaml(cfg)
            # Two channels at one energy, an empty-looking beam etc.: some are refusals by
            # design; `any` where acceptance is also right.
            # Extreme but finite sizes describe a (strange) scan: accepted or refused, both
            # right; so are the cases listed.
            extreme = v in ("RAW:1e308", "RAW:18446744073709551616", "RAW:[1e308, 1e308]")
            expect = "any" if extreme or (field, v) in {
                ("geometry.dsd", "RAW:500"), ("geometry.test_views", "RAW:-1"),
                ("name", "RAW:\"a\\nb\"")} else "error"
            add("simulate %s=%s" % (field, v[4:] if v.startswith("RAW:") else v),
                ["simulate", "c.yaml", "-o", "s"], expect,
                setup=lambda d, text=text: write(d, "c.yaml", text), outputs=["s"])
    for name, text in [
        ("empty", ""), ("binary", "\x00\x01\x02\xff"),
        ("truncated", dump_yaml(SCENE)[:57]),
        ("deep nesting", "[" * 100000),
        ("alias bomb", "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
            "%s: &%s [*%s, *%s, *%s, *%s, *%s, *%s, *%s, *%s, *%s]\n" % ((chr(98 + i), chr(98 + i))
                                                                        + (chr(97 + i),) * 9)
            for i in range(9))),
        ("unknown key", dump_yaml(dict(SCENE, extra=1))),
        ("hu missing", dump_yaml(dict(SCENE, object={"hu": {"path": "none.npy",
                                                            "voxel_mm": [1, 1, 1]}}))),
        ("hu huge header", dump_yaml(dict(SCENE, object={"hu": {"path": "hu.npy",
                                                                "voxel_mm": [1, 1, 1]}}))),
    ]:
        def setup(d, text=text, name=name):
            write(d, "c.yaml", text)
            if name == "hu huge header":
                npy(os.path.join(d, "hu.npy"), "<i2", (100000, 100000, 100000), bytes(64))
        add("simulate " + name, ["simulate", "c.yaml", "-o", "s"], "error", setup=setup,
            outputs=["s"])

    # --- --set overrides.
    for key, why in [(".".join(["a"] * 50000) + "=1", "deep key"), ("=1", "empty key"),
                     ("geometry..views=3", "empty segment"), ("channels.99.kev=1", "index"),
                     ("channels.18446744073709551616.kev=1", "huge index"),
                     ("geometry.views", "no value"), ("geometry.views=[[[", "bad YAML"),
                     ("geometry.views=" + "[" * 100000, "deep value")]:
        add("--set " + why, ["simulate", "base/scene.yaml", "-o", "s", "--set", key], "error",
            setup=use("scene.yaml"), outputs=["s"])

    # --- recon: method configs with one field made hostile.
    method_fields = [
        ("fdk", "filter", ["nope", "RAW:1"]),
        ("sart", "iterations", ["RAW:-1", "RAW:1e20", "text", "RAW:0"]),
        ("sart", "lambda", ["RAW:.nan", "RAW:-1", "RAW:0", "RAW:1e308"]),
        ("sart", "block_size", ["RAW:0", "RAW:-1", "RAW:1000000000000"]),
        ("cgls", "iterations", ["RAW:-1", "RAW:.nan"]),
        ("tv", "lambda", ["RAW:-1", "RAW:.nan", "RAW:.inf"]),
        ("r2gs", "iterations", ["RAW:-1", "RAW:1e20", "RAW:0"]),
        ("r2gs", "init.n_points", ["RAW:0", "RAW:-1", "RAW:1000000000000"]),
        ("r2gs", "lr.position.init", ["RAW:.nan", "RAW:-1", "RAW:.inf"]),
        ("r2gs", "scale_bounds", ["RAW:{min: 1.0, max: 0.5}", "RAW:{min: -1, max: 0.5}",
                                  "RAW:{min: .nan, max: 1}"]),
        ("r2gs", "densify.max_gaussians", ["RAW:0", "RAW:-5"]),
        ("r2gs", "loss.lambda_dssim", ["RAW:-1", "RAW:.nan", "RAW:2"]),
        ("r2gs", "loss.tv_patch", ["RAW:0", "RAW:100000"]),
        ("r2gs", "projection.cutoff", ["RAW:0", "RAW:.nan", "RAW:-3"]),
        ("r2gs", "eval_every", ["RAW:-1"]),
        ("r2gs", "device", ["gpu9", "RAW:1"]),
        ("r2gs", "method", ["nope", "RAW:[]"]),
        ("4dsg", "stage2.iterations", ["RAW:-1"]),
        ("4dsg", "stage2.curve_model.width", ["RAW:0", "RAW:-1", "RAW:100000000"]),
        ("4dsg", "holdout_channels", ["RAW:[nope]", "RAW:[40keV, 70keV]", "RAW:[40keV, 40keV]"]),
        ("4dsg", "structural", ["provided", "nope"]),
        ("basis", "stage2.basis.materials", ["RAW:[]", "RAW:[unobtainium]",
                                            "RAW:[water, water]",
                                            "RAW:[water, cortical_bone, iodine, fat, air]"]),
        ("naf", "rays_per_batch", ["RAW:0", "RAW:-1"]),
        ("naf", "samples_per_ray", ["RAW:0", "RAW:1000000000000"]),
        ("naf", "field.hash_grid.log2_table_size", ["RAW:64", "RAW:0"]),
        ("naf", "field.hash_grid.levels", ["RAW:0", "RAW:1000"]),
        ("naf", "attenuation_range", ["RAW:.nan", "RAW:-1", "RAW:0"]),
    ]
    for method, field, values in method_fields:
        for v in values:
            cfg = json.loads(json.dumps(METHODS[method]))
            set_path(cfg, field, v)
            text = dump_yaml(cfg)
            # Settings with a documented meaning at their edge: a block larger than the views
            # (one block: SIRT), no densification (cap 0), a heavier SSIM term, a TV patch
            # clamped to the volume.
            valid = (method, field, v) in {
                ("sart", "block_size", "RAW:1000000000000"),
                ("r2gs", "densify.max_gaussians", "RAW:0"), ("r2gs", "loss.lambda_dssim", "RAW:2"),
                ("r2gs", "loss.tv_patch", "RAW:100000")}
            add("recon %s %s=%s" % (method, field, v[4:] if v.startswith("RAW:") else v),
                ["recon", "m.yaml", "-s", "base/scene", "-o", "r"], "any" if valid else "error",
                setup=lambda d, text=text: (use("scene")(d), write(d, "m.yaml", text)),
                outputs=["r"])

    # --- recon options.
    opts = [
        ("scene missing", ["-s", "nowhere"]), ("scene is a file", ["-s", "base/fdk.yaml"]),
        ("eval grid 0", ["--eval-grid", "0"]), ("eval grid 1", ["--eval-grid", "1"]),
        ("eval grid 5", ["--eval-grid", "5"]), ("eval grid 100000", ["--eval-grid", "100000"]),
        ("eval grid text", ["--eval-grid", "x"]), ("eval grid 4096", ["--eval-grid", "4096"]),
        ("roi bad yaml", ["--eval-roi", "{["]), ("roi threshold 2", ["--eval-roi", "{threshold: 2}"]),
        ("roi erode -1", ["--eval-roi", "{erode_mm: -1}"]),
        ("roi erode everything", ["--eval-roi", "{erode_mm: 10000}"]),
        ("lpips garbage", ["--lpips-weights", "base/fdk.yaml"]),
    ]
    for why, extra in opts:
        args = ["recon", "base/fdk.yaml", "-s", "base/scene", "-o", "r"]
        if extra[0] == "-s":
            args = ["recon", "base/fdk.yaml", "-o", "r"] + extra
        else:
            args += extra
        add("recon " + why, args, "error", setup=use("fdk.yaml", "scene"), outputs=["r"])
    add("recon -o onto a file", ["recon", "base/fdk.yaml", "-s", "base/scene", "-o", "f.txt"],
        "error", setup=lambda d: (use("fdk.yaml", "scene")(d), write(d, "f.txt", "mine")))
    user_run = lambda d: (use("fdk.yaml", "scene")(d), write(os.path.join(d, "r"), "mine.txt",
                                                             "mine"))
    add("recon into a user's directory", ["recon", "base/fdk.yaml", "-s", "base/scene", "-o",
                                          "r"], "error", setup=user_run, outputs=["r"])
    add("recon --force keeps the user's file",
        ["recon", "base/fdk.yaml", "-s", "base/scene", "-o", "r", "--force"], "ok",
        setup=user_run, outputs=["r"])
    add("recon --force beside a stuck .old",
        ["recon", "base/fdk.yaml", "-s", "base/scene", "-o", "r", "--force"], "error",
        setup=lambda d: (user_run(d), write(d, ".r.old", "in the way")), outputs=["r"])
    add("recon --from-geometry missing",
        ["recon", "base/4dsg.yaml", "-s", "base/scene", "-o", "r", "--from-geometry", "none"],
        "error", setup=use("4dsg.yaml", "scene"), outputs=["r"])
    add("recon --from-geometry garbage",
        ["recon", "base/4dsg.yaml", "-s", "base/scene", "-o", "r", "--from-geometry", "g.st"],
        "error", setup=lambda d: (use("4dsg.yaml", "scene")(d), write(d, "g.st", "garbage")),
        outputs=["r"])
    add("recon --resume without a checkpoint",
        ["recon", "base/r2gs.yaml", "-s", "base/scene", "-o", "r", "--resume"], "error",
        setup=use("r2gs.yaml", "scene"), outputs=["r"])
    add("recon --checkpoint is a directory",
        ["recon", "base/r2gs.yaml", "-s", "base/scene", "-o", "r", "--resume",
         "--checkpoint", "dir"], "error",
        setup=lambda d: (use("r2gs.yaml", "scene")(d), os.makedirs(os.path.join(d, "dir"))),
        outputs=["r"])

    # --- scene directories corrupted (info and recon read them).
    def scene_case(why, corrupt, expect="error"):
        def setup(d):
            shutil.copytree(os.path.join(BASE, "scene"), os.path.join(d, "s"))
            corrupt(os.path.join(d, "s"))
        for cmd in (["info", "s"], ["recon", "base/fdk.yaml", "-s", "s", "-o", "r"]):
            add("%s on a scene with %s" % (cmd[0], why), cmd, expect,
                setup=lambda d, setup=setup: (use("fdk.yaml")(d), setup(d)), outputs=["r"])

    def proj_header(shape, descr="<f4", data=b"", fortran=False):
        return lambda s: npy(os.path.join(s, "projections.npy"), descr, shape, data, fortran)
    scene_case("projections truncated", lambda s: truncate(os.path.join(s, "projections.npy"), 100))
    scene_case("projections claiming 10^15 values", proj_header((100000, 100000, 100000)))
    scene_case("projections of wrong shape", proj_header((2, 3, 4, 5), data=bytes(480)))
    scene_case("projections in Fortran order", proj_header((2, 10, 12, 12), data=bytes(11520),
                                                           fortran=True), expect="any")
    scene_case("projections of strings", proj_header((2, 10, 12, 12), descr="<U4",
                                                     data=bytes(46080)))
    scene_case("projections of NaN", proj_header((2, 10, 12, 12),
                                                 data=f32([float("nan")] * 2880)))
    scene_case("projections of a negative dimension", proj_header((2, -10, 12, 12)))
    scene_case("references claiming 10^15 values",
               lambda s: npy(os.path.join(s, "references.npy"), "<f4", (100000, 100000, 100000)))
    scene_case("references of wrong shape",
               lambda s: npy(os.path.join(s, "references.npy"), "<f4", (2, 3, 3, 3), bytes(216)))
    scene_case("no scene.yaml", lambda s: os.remove(os.path.join(s, "scene.yaml")))
    scene_case("scene.yaml empty", lambda s: write(s, "scene.yaml", ""))
    for key, value in [("format_version", "99"), ("rows", "0"), ("rows", "13"),
                       ("dso", ".nan"), ("dsd", "-1"), ("pitch_u", "0"), ("nx", "100000"),
                       ("dx", ".inf"), ("label", "\"\""), ("tau", "5.0"), ("kev", "-40"),
                       ("beam", "laser"), ("train", "[0, 0, 99]")]:
        def corrupt(s, key=key, value=value):
            p = os.path.join(s, "scene.yaml")
            lines = open(p).read().split("\n")
            for i, line in enumerate(lines):
                if line.strip().lstrip("- ").startswith(key + ":"):
                    lines[i] = line[:line.index(key + ":") + len(key) + 1] + " " + value
                    break
            else:
                raise SystemExit("scene.yaml has no `%s:` line" % key)
            open(p, "w").write("\n".join(lines))
        scene_case("scene.yaml %s: %s" % (key, value), corrupt)

    # --- query and trained models.
    def model_case(why, corrupt, args=("--tau", "0.5"), expect="error", run="run-4dsg"):
        def setup(d):
            shutil.copytree(os.path.join(BASE, run), os.path.join(d, "run"))
            corrupt(os.path.join(d, "run"))
        add("query a model with " + why, ["query", "run", *args, "-o", "q.npy"], expect,
            setup=setup, outputs=["q.npy"])

    gs = lambda r: os.path.join(r, "gaussians.safetensors")
    model_case("a truncated file", lambda r: truncate(gs(r), 50))
    model_case("a header length of 2^63", lambda r: patch(gs(r), 0, struct.pack("<Q", 1 << 63)))
    model_case("another format", lambda r: st_edit_meta(gs(r), "format", lambda v: "nope/1"))
    for k, v in [("nx", 100000), ("nx", 0), ("dx", -1.0), ("dx", 0.0), ("nx", 9000)]:
        def corrupt(r, k=k, v=v):
            def e(info):
                info["geometry"]["volume"][k] = v
                if k == "nx" and v == 9000:
                    for a, b in [("nx", "dx"), ("ny", "dy"), ("nz", "dz")]:
                        info["geometry"]["volume"][a] = 9000
                        info["geometry"]["volume"][b] = 0.01
                return info
            st_edit_meta(gs(r), "info", e)
        model_case("volume %s = %s" % (k, v), corrupt)
    model_case("no channels", lambda r: st_edit_meta(gs(r), "info", lambda i: dict(
        i, channels=[], tau=[], coordinates=[])))
    model_case("τ not increasing", lambda r: st_edit_meta(gs(r), "info", lambda i: dict(
        i, tau=[1.0, 0.0])))
    model_case("τ NaN", lambda r: st_edit_meta(gs(r), "info", lambda i: dict(i, tau=[0.0, "NaN"])))
    for k, v in [("world_scale", "0"), ("world_scale", "NaN"), ("density_scale", "-1"),
                 ("scale_min", "1"), ("scale_max", "-1")]:
        model_case("%s %s" % (k, v), lambda r, k=k, v=v: st_edit_meta(gs(r), k, lambda _: v))
    model_case("densities of the wrong width",
               lambda r: st_edit_tensor_shape(gs(r), "densities_raw", [1, 1]))
    model_case("means of a huge shape",
               lambda r: st_edit_tensor_shape(gs(r), "means", [1 << 40, 3]))
    model_case("no model", lambda r: os.remove(gs(r)))
    model_case("basis file gone, queried in keV",
               lambda r: os.remove(os.path.join(r, "basis.safetensors")), ("--kev", "60"),
               run="run-basis")
    model_case("basis file truncated",
               lambda r: truncate(os.path.join(r, "basis.safetensors"), 40), ("--kev", "60"),
               run="run-basis")
    for args in [("--tau", "nan"), ("--tau", "inf"), ("--tau", "5"), ("--coordinate", "1e308"),
                 ("--kev", "-5"), ("--kev", "1000"), ("--kev", "nan"), ("--tau", "x")]:
        model_case("arguments " + " ".join(args), lambda r: None, args)
    add("query -o in a missing directory",
        ["query", "base/run-4dsg", "--tau", "0.5", "-o", "none/q.npy"], "error",
        setup=use("run-4dsg"))
    add("query -o onto a user's file", ["query", "base/run-4dsg", "--tau", "0.5", "-o",
                                        "mine.txt"], "error", setup=use("run-4dsg"))
    add("query -o onto the run's own volume",
        ["query", "run", "--tau", "0.5", "-o", "run/40keV.npy"], "error",
        setup=lambda d: shutil.copytree(os.path.join(BASE, "run-4dsg"), os.path.join(d, "run")))
    add("query an r2gs run", ["query", "base/run-r2gs", "--tau", "0.5", "-o", "q.npy"], "error",
        setup=use("run-r2gs"), outputs=["q.npy"])
    add("query an FDK run", ["query", "base/run-fdk", "--tau", "0.5", "-o", "q.npy"], "error",
        setup=use("run-fdk"), outputs=["q.npy"])

    # --- stage-1 checkpoints (--from-geometry).
    def geometry_case(why, corrupt):
        def setup(d):
            use("4dsg.yaml", "scene")(d)
            shutil.copy(os.path.join(BASE, "run-4dsg", "geometry.safetensors"),
                        os.path.join(d, "g.safetensors"))
            corrupt(os.path.join(d, "g.safetensors"))
        add("--from-geometry with " + why,
            ["recon", "base/4dsg.yaml", "-s", "base/scene", "-o", "r", "--from-geometry",
             "g.safetensors"], "error", setup=setup, outputs=["r"])
    geometry_case("a view beyond the scene", lambda p: st_edit_meta(p, "views", lambda v: v + [99]))
    geometry_case("a view twice", lambda p: st_edit_meta(p, "views", lambda v: v + v[:1]))
    geometry_case("no views", lambda p: st_edit_meta(p, "views", lambda v: []))
    geometry_case("steps of 3 entries", lambda p: st_edit_meta(p, "steps", lambda v: v[:3]))
    def other_settings(v):
        v["settings"]["iterations"] += 1
        return v
    geometry_case("another fingerprint", lambda p: st_edit_meta(p, "fingerprint", other_settings))
    geometry_case("a truncated file", lambda p: truncate(p, 100))
    geometry_case("world scale 0", lambda p: st_edit_meta(p, "world", lambda v: dict(v, scale=0.0)))

    # --- resume files.
    def resume_case(method, why, corrupt):
        def setup(d):
            shutil.copy(os.path.join(BASE, "long-%s.yaml" % method), os.path.join(d, "m.yaml"))
            use("scene")(d)
            shutil.copy(os.path.join(BASE, "stopped-%s.ckpt" % method), os.path.join(d, "c.ckpt"))
            corrupt(os.path.join(d, "c.ckpt"))
        add("resume %s with %s" % (method, why),
            ["recon", "m.yaml", "-s", "base/scene", "-o", "r", "--resume", "--checkpoint",
             "c.ckpt"], "error", setup=setup, outputs=["r"])

    def cur(edit):
        return lambda p: st_edit_meta(p, "current", edit)

    def progress(key, value):
        def e(v):
            v["progress"][key] = value
            return v
        return cur(e)

    def trainer(key, value):
        def e(v):
            v["trainer"][key] = value
            return v
        return cur(e)
    resume_case("r2gs", "an iteration beyond the end", progress("iteration", 10 ** 9))
    resume_case("r2gs", "a negative time", progress("start_train_s", -5.0))
    resume_case("r2gs", "a window beyond the iterations", progress("window_n", 10 ** 9))
    resume_case("r2gs", "a random position beyond the stream",
                trainer("rng_word_pos", str(2 ** 100)))
    resume_case("r2gs", "a random position of text", trainer("rng_word_pos", "x"))
    resume_case("r2gs", "a view order with a foreign view", trainer("order", [0, 999]))
    resume_case("r2gs", "a view order with a repeat", trainer("order", [1, 1]))
    resume_case("r2gs", "another stage index", cur(lambda v: dict(v, index=5)))
    resume_case("r2gs", "a truncated file", lambda p: truncate(p, 200))
    resume_case("r2gs", "another format", lambda p: st_edit_meta(p, "format", lambda v: "x/1"))
    resume_case("naf", "an iteration beyond the end", cur(lambda v: dict(v, iteration=10 ** 9)))
    resume_case("naf", "an order of one view", cur(lambda v: dict(v, order=[0], iteration=3)))
    resume_case("naf", "a negative loss sum", cur(lambda v: dict(v, loss_sum=-1.0)))
    resume_case("naf", "more losses than iterations", cur(lambda v: dict(v, loss_n=10 ** 9)))
    resume_case("naf", "another channel", cur(lambda v: dict(v, channel=7)))
    resume_case("naf", "done beyond the channels", lambda p: st_edit_meta(p, "done", lambda v: 9))

    # --- decompose.
    def decompose_case(why, corrupt, extra=(), expect="error"):
        def setup(d):
            shutil.copytree(os.path.join(BASE, "run-fdk"), os.path.join(d, "run"))
            use("scene")(d)
            corrupt(d)
        add("decompose " + why, ["decompose", "run", "-s", "base/scene", "-o", "dec",
                                 "--basis", "water,cortical_bone", *extra], expect,
            setup=setup, outputs=["dec"])
    vol = lambda d: os.path.join(d, "run", "40keV.npy")
    decompose_case("a volume missing", lambda d: os.remove(vol(d)))
    decompose_case("a volume claiming 10^15 values",
                   lambda d: npy(vol(d), "<f4", (100000, 100000, 100000)))
    decompose_case("a volume of the wrong shape", lambda d: npy(vol(d), "<f4", (2, 2, 2),
                                                                f32([0.0] * 8)))
    decompose_case("a volume of NaN", lambda d: npy(vol(d), "<f4", (12, 12, 12),
                                                    f32([float("nan")] * 1728)))
    decompose_case("a volume of f64", lambda d: npy(vol(d), "<f8", (12, 12, 12), bytes(13824)))
    decompose_case("an unknown material", lambda d: None, ("--basis", "unobtainium"))
    decompose_case("a material twice", lambda d: None, ("--basis", "water,water"))
    decompose_case("five materials", lambda d: None,
                   ("--basis", "water,cortical_bone,iodine,fat,air"))
    for kev in ["-1", "1000", "nan", "x"]:
        decompose_case("VMI at %s keV" % kev, lambda d: None, ("--kev", kev))
    decompose_case("into a directory with the user's file",
                   lambda d: write(os.path.join(d, "dec"), "mine.txt", "mine"))
    decompose_case("into a directory being written", lambda d: (
        os.makedirs(os.path.join(d, ".dec.partial")),
        write(os.path.join(d, ".dec.partial"), ".prism-writer", str(os.getppid()))))
    add("decompose with another scene", ["decompose", "base/run-fdk", "-s", "base/imported",
                                         "-o", "dec"], "error",
        setup=use("run-fdk", "imported"), outputs=["dec"])

    # --- export.
    def export_case(why, extra, setup_extra=None, expect="error", replaces=()):
        def setup(d):
            use("scene", "run-fdk")(d)
            if setup_extra:
                setup_extra(d)
        add("export " + why, ["export", "base/scene", *extra], expect, setup=setup,
            outputs=["e"], replaces=replaces)
    export_case("an unknown format", ["base/run-fdk", "-o", "e", "--format", "jpg"])
    export_case("no format", ["base/run-fdk", "-o", "e"])
    export_case("a volume of another grid", ["v.npy", "-o", "e", "--format", "nii"],
                lambda d: npy(os.path.join(d, "v.npy"), "<f4", (2, 2, 2), f32([0.0] * 8)))
    export_case("a volume claiming 10^15 values", ["v.npy", "-o", "e", "--format", "nii"],
                lambda d: npy(os.path.join(d, "v.npy"), "<f4", (100000, 100000, 100000)))
    export_case("a text file as volume", ["base/fdk.yaml", "-o", "e", "--format", "nii"],
                lambda d: use("fdk.yaml")(d))
    export_case("-o onto a file", ["base/run-fdk", "-o", "mine.txt", "--format", "nii"])
    export_case("over the user's file", ["base/run-fdk", "-o", "e", "--format", "mha"],
                lambda d: write(os.path.join(d, "e"), "40keV.mha", "mine"))
    export_case("a directory without a manifest", ["d", "-o", "e", "--format", "nii"],
                lambda d: os.makedirs(os.path.join(d, "d")))
    export_case("two volumes of one name", ["base/run-fdk", "base/run-fdk", "-o", "e",
                                            "--format", "nii"])

    # --- import.
    def import_case(why, edit, expect="error", files=None):
        cfg = json.loads(json.dumps(IMPORT))
        edit(cfg)
        text = dump_yaml(cfg)

        def setup(d):
            shutil.copytree(os.path.join(BASE, "import"), os.path.join(d, "i"))
            write(os.path.join(d, "i"), "import.yaml", text)
            if files:
                files(os.path.join(d, "i"))
        add("import " + why, ["import", "i/import.yaml", "-o", "s"], expect, setup=setup,
            outputs=["s"])
        if expect == "error":
            add("import --dry-run " + why, ["import", "i/import.yaml", "-o", "s", "--dry-run"],
                "any", setup=setup, outputs=["s"])

    def at(path, value):
        return lambda c: set_path(c, path, value)
    import_case("a trillion views", at("angles.count", 10 ** 12))
    import_case("no angles", at("angles", {}))
    import_case("angles listed with NaN", at("angles", {"deg": ["RAW:.nan", 1]}))
    import_case("an angle file missing", at("angles", {"file": "none.txt", "unit": "deg"}))
    import_case("an angle file of text", at("angles", {"file": "a.txt", "unit": "deg"}),
                files=lambda i: write(i, "a.txt", "abc\n"))
    import_case("angles in radians beyond 8 turns", at("angles", {"file": "a.txt", "unit": "rad"}),
                files=lambda i: write(i, "a.txt", "\n".join(str(v * 100.0) for v in range(16))))
    import_case("a view listed twice", at("channels.0.views", [1, 1] + list(range(2, 16))))
    import_case("a view beyond the scan", at("channels.0.views", [99] + list(range(1, 16))))
    import_case("fewer images than views", at("angles.count", 20))
    import_case("images missing", at("channels.0.line_integrals.path", "none.npy"))
    import_case("images of another detector", at("geometry.prism.detector.rows", 13))
    import_case("images claiming 10^15 values", lambda c: None,
                files=lambda i: npy(os.path.join(i, "p.npy"), "<f4", (100000, 100000, 100000)))
    import_case("images of NaN", lambda c: None,
                files=lambda i: npy(os.path.join(i, "p.npy"), "<f4", (16, 12, 12),
                                    f32([float("nan")] * 2304)))
    import_case("images of complex values", lambda c: None,
                files=lambda i: npy(os.path.join(i, "p.npy"), "<c8", (16, 12, 12), bytes(18432)))
    import_case("counts without a flat", lambda c: c["channels"][0].update(
        line_integrals=None, counts={"path": "counts.npy"}))
    import_case("counts with both sources", at("channels.0.counts", {"path": "counts.npy"}))
    for v in ["RAW:0", "RAW:-1", "RAW:.nan"]:
        import_case("min_counts " + v[4:], at("min_counts", v))
    flat_counts = lambda c: (c["channels"][0].update(line_integrals=None,
                                                      counts={"path": "counts.npy"}),
                             c.update(flat={"path": "f.tif"}))
    import_case("a flat TIFF of another size", flat_counts,
                files=lambda i: tiff(os.path.join(i, "f.tif"), 1, 13, 12))
    import_case("a flat TIFF truncated", flat_counts,
                files=lambda i: (shutil.copy(os.path.join(i, "flat.tif"),
                                             os.path.join(i, "f.tif")),
                                 truncate(os.path.join(i, "f.tif"), 30)))
    import_case("a flat TIFF declaring 2^32 rows", flat_counts,
                files=lambda i: tiff(os.path.join(i, "f.tif"), 1, 12, 0xFFFFFFFF, strip=b""))
    import_case("a PackBits flat of 16000² pixels", flat_counts,
                files=lambda i: tiff(os.path.join(i, "f.tif"), 1, 16000, 16000, bits=8,
                                     compression=32773,
                                     strip=bytes([0x81, 0]) * 125 * 16000))
    import_case("a flat TIFF in RGB", flat_counts,
                files=lambda i: write_bytes(i, "f.tif", b"II*\0\x08\0\0\0" + bytes(20)))
    import_case("a raw file of the wrong size", at("channels.0.line_integrals",
                                                   {"path": "p.raw", "raw": {
                                                       "dtype": "f32", "shape": [16, 12, 12]}}),
                files=lambda i: write_bytes(i, "p.raw", bytes(100)))
    import_case("a raw dtype unknown", at("channels.0.line_integrals",
                                          {"path": "p.raw", "raw": {"dtype": "f128",
                                                                    "shape": [16, 12, 12]}}),
                files=lambda i: write_bytes(i, "p.raw", bytes(100)))
    import_case("an HDF5 dataset in a non-HDF5 file",
                at("channels.0.line_integrals", {"path": "p.npy", "dataset": "/exchange/data"}))
    import_case("an HDF5 file of garbage",
                at("channels.0.line_integrals", {"path": "g.h5", "dataset": "/exchange/data"}),
                files=lambda i: write_bytes(i, "g.h5", b"\x89HDF\r\n\x1a\n" + bytes(64)))
    import_case("select.views 0", at("select.views", 0))
    import_case("select.views beyond the scan", at("select.views", 1000))
    import_case("test views beyond the rest", at("select.test_views", 1000))
    import_case("no geometry", lambda c: c.pop("geometry"))
    import_case("an unknown reference", at("select.reference", "magic"))
    import_case("no channels", at("channels", []))
    import_case("a channel label with a newline", at("channels.0.label", "a\nb"), expect="any")
    for why, extra in [("range -5", ["--range", "-5"]), ("step 0", ["--step", "0"]),
                       ("step nan", ["--step", "nan"]), ("unknown method", ["--method", "x"])]:
        add("axis " + why, ["axis", "base/import/import.yaml", *extra], "error",
            setup=use("import"))

    # --- experiment suites.
    def suite_case(why, edit, expect="error", flags=("--dry-run",)):
        suite = {"name": "s", "scenes": {"a": {"config": "base/scene.yaml"}},
                 "methods": {"fdk": {"config": "base/fdk.yaml"}},
                 "studies": [{"name": "t", "kind": "table", "methods": ["fdk"],
                              "scenes": ["a"]}]}
        edit(suite)
        text = dump_yaml(suite)
        add("experiment " + why, ["experiment", "suite.yaml", "-o", "res", *flags], expect,
            setup=lambda d: (use("scene.yaml", "fdk.yaml")(d), write(d, "suite.yaml", text)),
            outputs=["res"])
    suite_case("a missing scene config", at("scenes.a.config", "none.yaml"))
    suite_case("an unknown method in a study", at("studies.0.methods", ["nope"]))
    suite_case("an unknown scene in a study", at("studies.0.scenes", ["nope"]))
    suite_case("no studies", at("studies", []))
    suite_case("two studies of one name", lambda s: s["studies"].append(dict(s["studies"][0])))
    suite_case("a scene label with a newline", at("scenes.a.label", "a\nb"))
    suite_case("a method label with a newline", at("methods.fdk.label", "a\n#SBATCH x"))
    suite_case("jobs -1", at("jobs", -1))
    suite_case("jobs 100000", at("jobs", 100000), expect="ok")
    suite_case("evaluation grid 0", at("evaluation", {"grid": 0}))
    suite_case("evaluation grid 100000", at("evaluation", {"grid": 100000}))
    suite_case("roi threshold 2", at("evaluation", {"roi": {"threshold": 2}}))
    suite_case("a scene's roi erode -1", at("scenes.a.roi", {"erode_mm": -1}))
    suite_case("a bad --set in a method", at("methods.fdk.set", ["=1"]))
    suite_case("an unknown study kind", at("studies.0.kind", "magic"))
    suite_case("an unknown field", at("extra", 1))
    suite_case("a slurm partition with a newline", at("slurm", {"partition": "a\nrm -rf ~"}),
               flags=("--slurm", "--dry-run"))
    add("experiment with a suite file missing", ["experiment", "none.yaml", "-o", "res"], "error",
        outputs=["res"])
    add("experiment collect from nothing", ["experiment", "collect", "base/suite.yaml", "-o",
                                            "res"], "any", setup=use("suite.yaml"),
        outputs=["res"])

    # --- report.
    def report_case(why, corrupt, expect="error"):
        def setup(d):
            shutil.copytree(os.path.join(BASE, "run-fdk"), os.path.join(d, "run"))
            corrupt(os.path.join(d, "run"))
        add("report " + why, ["report", "run"], expect, setup=setup)
    m = lambda r: os.path.join(r, "metrics.json")
    report_case("metrics.json missing", lambda r: os.remove(m(r)))
    report_case("metrics.json truncated", lambda r: truncate(m(r), 30))
    report_case("metrics.json of garbage", lambda r: write(r, "metrics.json", "\x00\xff"))
    report_case("a psnr of null", lambda r: json_edit(m(r), lambda j: j["channels"][0].update(
        psnr=None)), expect="any")
    report_case("a psnr of text", lambda r: json_edit(m(r), lambda j: j["channels"][0].update(
        psnr="much")))
    report_case("a psnr of inf", lambda r: json_edit(m(r), lambda j: j["channels"][0].update(
        psnr="inf")), expect="ok")
    report_case("no channels", lambda r: json_edit(m(r), lambda j: j.update(channels=[])),
                expect="any")
    report_case("holdout.json of garbage", lambda r: write(r, "holdout.json", "[{"))
    add("report a missing directory", ["report", "none"], "error")
    return out


# ---------------------------------------------------------------------------------------------
# Helpers of the cases

BASE = None  # the base artefacts' directory, set in main


def write(d, name, text):
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "w") as f:
        f.write(text)


def write_bytes(d, name, data):
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def truncate(path, n):
    with open(path, "r+b") as f:
        f.truncate(n)


def patch(path, at, data):
    with open(path, "r+b") as f:
        f.seek(at)
        f.write(data)


def json_edit(path, edit):
    j = json.load(open(path))
    edit(j)
    json.dump(j, open(path, "w"))


def use(*names):
    """Link the base artefacts `names` under `base/` of the case directory."""
    def setup(d):
        os.makedirs(os.path.join(d, "base"), exist_ok=True)
        for n in names:
            dst = os.path.join(d, "base", n)
            if not os.path.exists(dst):
                src = os.path.join(BASE, n)
                if os.path.isdir(src):
                    shutil.copytree(src, dst)
                else:
                    shutil.copy(src, dst)
    return setup


def snapshot(d):
    files = {}
    for root, _, names in os.walk(d):
        for n in names:
            p = os.path.join(root, n)
            try:
                files[os.path.relpath(p, d)] = hashlib.sha256(open(p, "rb").read()).hexdigest()
            except OSError:
                pass
    return files


def run_case(prism, case, work, timeout):
    d = os.path.join(work, "case")
    shutil.rmtree(d, ignore_errors=True)
    os.makedirs(d)
    # The user's own file, beside the inputs and in every output directory.
    write(d, "mine.txt", "mine")
    if case.setup:
        case.setup(d)
    before = snapshot(d)
    t0 = time.time()
    try:
        r = subprocess.run([prism, *case.args], cwd=d, capture_output=True, timeout=timeout)
        rc, text = r.returncode, (r.stdout + r.stderr).decode("utf-8", "replace")
    except subprocess.TimeoutExpired as e:
        rc, text = None, ((e.stdout or b"") + (e.stderr or b"")).decode("utf-8", "replace")
    seconds = time.time() - t0
    after = snapshot(d)
    lost = [f for f, h in before.items()
            if f not in case.replaces and after.get(f) != h
            and not (case.expect == "ok" and not f.endswith("mine.txt")
                     and f.split(os.sep)[0] in case.outputs)]
    lines = [l for l in text.strip().split("\n") if l.strip()]
    message = lines[-1] if lines else ""
    if rc is None:
        outcome = "hang"
    elif rc == -signal.SIGABRT or "memory allocation of" in text:
        outcome = "abort"
    elif rc == -signal.SIGKILL or rc == 137:
        outcome = "killed"
    elif rc < 0 or rc == 101 or "panicked at" in text:
        outcome = "crash"
    elif lost:
        outcome = "lost file"
    elif rc == 0 and case.expect == "error":
        outcome = "silent success"
    elif rc != 0 and case.expect == "ok":
        outcome = "false refusal"
    elif rc != 0 and "error:" not in text:
        outcome = "unclear error"
    else:
        outcome = "clean"
    return {"case": case.name, "args": case.args, "expect": case.expect, "status": rc,
            "outcome": outcome, "seconds": round(seconds, 2), "message": message[:400],
            "lost": lost}


def main():
    global BASE
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--prism", default=os.path.join(ROOT, "target", "release", "prism"))
    ap.add_argument("--work", default=None, help="scratch directory (default: a temporary one)")
    ap.add_argument("--only", default=None, help="run the cases whose name contains this text")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case")
    ap.add_argument("--json", default=None, help="write every case's outcome here")
    a = ap.parse_args()
    prism = os.path.abspath(a.prism)
    work = a.work or tempfile.mkdtemp(prefix="prism-sweep-")
    os.makedirs(work, exist_ok=True)
    BASE = os.path.join(work, "base")
    t0 = time.time()
    Base(prism, BASE).build()
    print("base artefacts built in %.0f s (%s)" % (time.time() - t0, BASE), flush=True)
    all_cases = [c for c in cases() if not a.only or a.only in c.name]
    results = []
    for i, c in enumerate(all_cases):
        r = run_case(prism, c, work, a.timeout)
        results.append(r)
        mark = "  " if r["outcome"] == "clean" else "!!"
        print("%s %3d %-14s %5.1fs  %s → %s" % (mark, i + 1, r["outcome"], r["seconds"], c.name,
                                                r["message"][:160]), flush=True)
    counts = {}
    for r in results:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    print("\n%d cases in %.0f s: %s" % (len(results), time.time() - t0, ", ".join(
        "%d %s" % (n, k) for k, n in sorted(counts.items()))))
    if a.json:
        json.dump({"cases": results, "counts": counts}, open(a.json, "w"), indent=1)
    return 0 if set(counts) <= {"clean"} else 1


if __name__ == "__main__":
    sys.exit(main())
