#!/bin/sh
# Regenerate data/real/bird/reference-tv-prism-{50,80,120}kvp.npy, the references configs/real/bird.yaml
# reads: the bird imported with each channel's non-negative TV from all 720 views reconstructed here
# (configs/real/bird-references.yaml, about 10 min on 2 cores), its references split per channel
# ([1, 512, 512] float32 each, mm⁻¹). Needs a built prism (PRISM, default target/release/prism) and numpy.
#   sh scripts/bird_references.sh [WORK_DIR]
set -eu
prism=${PRISM:-target/release/prism}
work=${1:-runs/bird-references}
[ -x "$prism" ] || { echo "bird_references: $prism not found (cargo build --release -p prism-cli)" >&2; exit 1; }
"$prism" import configs/real/bird-references.yaml -o "$work/scene"
python3 - "$work/scene/references.npy" <<'PY'
import sys
import numpy as np
refs = np.load(sys.argv[1])
assert refs.shape == (3, 1, 512, 512) and refs.dtype == np.float32, (refs.shape, refs.dtype)
for i, kvp in enumerate(("50", "80", "120")):
    np.save(f"data/real/bird/reference-tv-prism-{kvp}kvp.npy", np.ascontiguousarray(refs[i]))
print("wrote data/real/bird/reference-tv-prism-{50,80,120}kvp.npy")
PY
