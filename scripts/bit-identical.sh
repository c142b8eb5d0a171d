#!/bin/sh
# Do two prism binaries produce byte-identical results? For refactors that must not change a bit.
#
#   sh scripts/bit-identical.sh OLD_PRISM NEW_PRISM [OUT_DIR] [--main-job]
#
# Each binary simulates the smoke scene (configs/smoke.yaml) and runs FDK, SART, R²-Gaussian,
# 4D-SG (stage 1 + GSC-Net stage 2), the 4D-SG basis head and NAF on it with short schedules;
# `--main-job` adds the README main job (phantom-4mono: FDK, SART, 4D-SG with a held-out channel,
# the 85 keV query; a few minutes per binary). Then every `.npy` file (scene and volumes) must be
# byte-identical, and every `metrics.json` identical once its wall-time fields (`wall_s`,
# `time_s`, …) are removed. Exit status 0 when all match, 1 otherwise (the differing files named).
set -eu
[ $# -ge 2 ] || { sed -n '2,11p' "$0"; exit 2; }
old=$(realpath "$1"); new=$(realpath "$2"); shift 2
out=runs/bit-identical; main_job=no
for a in "$@"; do
    case "$a" in
        --main-job) main_job=yes ;;
        *) out=$a ;;
    esac
done
here=$(cd "$(dirname "$0")/.." && pwd)
cd "$here"

# Short schedules: densification, evaluation and stage 2 all happen within them.
gauss="--set iterations=60 --set init.n_points=1500 --set densify.from=10 --set densify.until=50
       --set densify.every=20 --set densify.grad_threshold=2.0e-6 --set eval_every=30"
run_all() { # binary dir
    p=$1; d=$2
    rm -rf "$d"; mkdir -p "$d"
    $p simulate configs/smoke.yaml -o "$d/scene" >/dev/null
    $p recon configs/recon/fdk.yaml -s "$d/scene" -o "$d/fdk" >/dev/null
    $p recon configs/recon/sart.yaml -s "$d/scene" -o "$d/sart" --set iterations=3 >/dev/null
    # shellcheck disable=SC2086
    $p recon configs/recon/r2gs.yaml -s "$d/scene" -o "$d/r2gs" $gauss >/dev/null 2>&1
    # shellcheck disable=SC2086
    $p recon configs/recon/4dsg.yaml -s "$d/scene" -o "$d/4dsg" $gauss \
        --set stage2.iterations=30 --set stage2.curve_model.table_size=256 >/dev/null 2>&1
    # shellcheck disable=SC2086
    $p recon configs/recon/4dsg-basis.yaml -s "$d/scene" -o "$d/basis" $gauss \
        --set stage2.iterations=30 >/dev/null 2>&1
    $p recon configs/recon/naf.yaml -s "$d/scene" -o "$d/naf" --set iterations=60 \
        --set eval_every=30 --set samples_per_ray=32 --set field.hash_grid.log2_table_size=12 \
        >/dev/null 2>&1
    $p query "$d/4dsg" --coordinate 85 -o "$d/4dsg/query-85.npy" >/dev/null 2>&1
    if [ "$main_job" = yes ]; then
        m="$d/main-job"
        $p simulate configs/phantom-4mono.yaml -o "$m/scene" >/dev/null
        $p recon configs/recon/fdk.yaml -s "$m/scene" -o "$m/fdk" >/dev/null
        $p recon configs/recon/sart.yaml -s "$m/scene" -o "$m/sart" >/dev/null
        $p recon configs/recon/4dsg-holdout.yaml -s "$m/scene" -o "$m/4dsg" >/dev/null 2>&1
        $p query "$m/4dsg" --coordinate 85 -o "$m/4dsg/query-85keV.npy" >/dev/null 2>&1
    fi
}

echo "old: $old"; run_all "$old" "$out/old"
echo "new: $new"; run_all "$new" "$out/new"

python3 - "$out/old" "$out/new" <<'PY'
import json, pathlib, sys
old, new = map(pathlib.Path, sys.argv[1:3])
def timeless(x):
    if isinstance(x, dict):
        return {k: timeless(v) for k, v in x.items()
                if not (k in ("wall_s", "time_s", "seconds") or k.endswith("_s") or "time" in k)}
    if isinstance(x, list):
        return [timeless(v) for v in x]
    return x
files = sorted(p.relative_to(old) for p in old.rglob("*")
               if p.is_file() and (p.suffix == ".npy" or p.name == "metrics.json"))
bad, n_npy, n_metrics = [], 0, 0
for rel in files:
    a, b = old / rel, new / rel
    if not b.exists():
        bad.append(f"{rel}: missing in {new}")
    elif rel.suffix == ".npy":
        n_npy += 1
        if a.read_bytes() != b.read_bytes():
            bad.append(f"{rel}: bytes differ")
    else:
        n_metrics += 1
        if timeless(json.loads(a.read_text())) != timeless(json.loads(b.read_text())):
            bad.append(f"{rel}: metrics differ")
extra = sorted(p.relative_to(new) for p in new.rglob("*.npy") if not (old / p.relative_to(new)).exists())
bad += [f"{rel}: only in {new}" for rel in extra]
print(f"compared {n_npy} .npy files and {n_metrics} metrics.json files")
for line in bad:
    print("DIFFERS", line)
print("bit-identical" if not bad else f"{len(bad)} difference(s)")
sys.exit(1 if bad else 0)
PY
