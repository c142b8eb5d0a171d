"""Convert Cueva et al.'s published TV references of the bird scan into Prism volumes.

Their repository (github.com/evelyncueva/synergistic_multi_spectral_ct_dTV, MPL-2.0) ships each
spectrum's reference, non-negative TV from all 720 views (500 forward-backward iterations, their
α = 5e-3 at 50 kVp and 2e-3 at 80 and 120 kVp), as `data/bird/E{0,1,2}_512x512_reference_
reconstruction_alpha_*.npy`: a pickled list [ODL element, iterations, objective]. This reads the
element's array without ODL (its classes are replaced by stubs that keep their state) and writes it
in Prism's axes as float32 `[1, 512, 512]` (`[nz, ny, nx]`, μ in mm⁻¹):

    prism[y, x] = odl[511 − x, 511 − y]

ODL indexes an image `[x, y]` with x along its first axis; the map was found by comparing each
spectrum's 720-view filtered backprojection in both tools (ODL's `*_FBP_reference.npy` against
`prism import configs/real/bird-dtv.yaml --set select.reference=fdk`): 36.7 / 36.3 / 32.0 dB with
this map, against 18.5–22.4 dB for the seven other flips and transposes.

Usage: python3 scripts/bird_dtv_references.py <their data/bird folder> <out folder>
"""

import pickle
import sys
from pathlib import Path

import numpy as np

FILES = {
    "50kvp": "E0_512x512_reference_reconstruction_alpha_0_005.npy",
    "80kvp": "E1_512x512_reference_reconstruction_alpha_0_002.npy",
    "120kvp": "E2_512x512_reference_reconstruction_alpha_0_002.npy",
}


class _Stub:
    """Stands in for any ODL class: keeps its constructor arguments and pickled state."""

    def __init__(self, *args, **_kwargs):
        self.args = args

    def __setstate__(self, state):
        self.state = state


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module.split(".")[0] == "odl":
            return type(name, (_Stub,), {})
        return super().find_class(module, name)


def _arrays(obj, seen):
    """Every numeric ndarray reachable from `obj`."""
    if id(obj) in seen:
        return
    seen.add(id(obj))
    if isinstance(obj, np.ndarray) and obj.dtype != object:
        yield obj
    elif isinstance(obj, (list, tuple, np.ndarray)):
        for x in obj:
            yield from _arrays(x, seen)
    elif isinstance(obj, dict):
        for x in obj.values():
            yield from _arrays(x, seen)
    elif hasattr(obj, "__dict__"):
        for x in vars(obj).values():
            yield from _arrays(x, seen)


def read_reference(path):
    with open(path, "rb") as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            np.lib.format.read_array_header_1_0(f)
        else:
            np.lib.format.read_array_header_2_0(f)
        obj = _Unpickler(f, encoding="latin1").load()
    images = [a for a in _arrays(obj, set()) if a.size == 512 * 512]
    if len(images) != 1:
        raise SystemExit(f"{path}: expected one 512 × 512 image, found {len(images)}")
    return images[0].reshape(512, 512).astype(np.float64)


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    for label, name in FILES.items():
        odl = read_reference(src / name)
        prism = odl[::-1, ::-1].T.astype(np.float32)[None]
        target = out / f"reference-tv-cueva-{label}.npy"
        np.save(target, np.ascontiguousarray(prism))
        print(f"{target}: {prism.shape}, max {prism.max():.4f} mm⁻¹")


if __name__ == "__main__":
    main()
