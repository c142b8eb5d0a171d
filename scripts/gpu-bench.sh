#!/bin/sh
# The GPU measurement in one command (issue: "the GPU path proven"): the wgpu parity tests, the
# render bench at 100 000 Gaussians on a 512² detector, and R²-Gaussian and 4D-SG end to end on a
# --paper-scale chest scene, all on the wgpu backend.
#
# GPU machines often have no Rust toolchain and no registry, so the work is split in two halves:
#
#   sh scripts/gpu-bench.sh package [PACK]       # on a machine with cargo: build and pack
#   sh scripts/gpu-bench.sh run [PACK] [OUT]     # on the GPU machine, from the repository root
#   sh scripts/gpu-bench.sh all [PACK] [OUT]     # both, where one machine has cargo and a GPU
#
# PACK (default target/gpu-bench) holds stripped binaries (prism and the render bench in release,
# the four library test binaries holding the wgpu parity tests as CI builds them), each also
# compressed (.xz where xz is installed, else .gz; `run` unpacks binaries that arrived only
# compressed), a Vulkan loader (libvulkan.so.1), glvnd's libGLdispatch.so.0 (which the NVIDIA
# driver's Vulkan ICD needs) and MANIFEST.txt.
#
# Sizes (2026-11, xz -6): prism 75 MB stripped, 13 MB as .xz; the render bench 8 MB, the test binaries
# 10-16 MB each as .xz (gzip: a third larger). Where a transfer is limited (64 MiB, say, for the
# pack and the 25 MB repository together), carry lib/, the compressed prism and render bench and
# the compressed tests that fit (tests/prism_render first: the kernels' parity); `run` skips the
# test binaries that did not come and says so in summary.txt.
# `run` needs the repository's configs/ and data/ (the chest scene is simulated from data/ct/) and
# writes OUT (default runs/gpu-bench): one log per step, the run directories, summary.txt (appended
# to, one line per step with its exit status and wall time).
# Environment for `run`: GPU_BENCH_BUDGET=default|paper (recon configs: the CPU defaults, or the
# paper's 30k-iteration budgets), GPU_BENCH_STEPS (default "tests bench scene r2gs 4dsg"),
# GPU_BENCH_LIMIT (seconds per step, default none: a step past it is stopped and recorded with
# rc=124, and its log and run directory keep what it reached).
#
# Vulkan on the GPU machine: the NVIDIA driver's ICD (nvidia_icd.json) is used when installed,
# in the system's ICD folders or under the driver's own /usr/local/nvidia (selected with
# VK_DRIVER_FILES); otherwise, where the driver's libGLX_nvidia.so.0 exists, an ICD file naming it
# is written into OUT and selected with VK_ICD_FILENAMES. wgpu then reports the adapter it picked
# in the logs.
set -eu

mode=${1:-}
pack=${2:-target/gpu-bench}
out=${3:-runs/gpu-bench}

die() {
    echo "gpu-bench: $*" >&2
    exit 1
}

# Executables cargo reports for a build (`--message-format=json`), one per line.
executables() {
    sed -n 's/.*"executable":"\([^"]*\)".*/\1/p'
}

package() {
    command -v cargo >/dev/null || die "package: cargo not found (run this half where Rust is installed)"
    rm -rf "$pack"
    mkdir -p "$pack/bin" "$pack/tests" "$pack/lib"
    # One release build for the binary and the bench (one feature set, so the GPU stack is
    # compiled once); the test binaries come from the test build CI makes (the README's test
    # command), which is reused when it is already there.
    echo "gpu-bench: building prism and the render bench with --features wgpu (release)" >&2
    cargo build --release --workspace --features wgpu --bins --benches --message-format=json \
        >"$pack/build.json"
    cp target/release/prism "$pack/bin/prism"
    bench=$(grep '"name":"render"' "$pack/build.json" | executables | tail -n 1)
    [ -n "$bench" ] || die "package: cargo reported no render bench executable"
    cp "$bench" "$pack/bin/render-bench"
    echo "gpu-bench: building the test binaries with --features wgpu,ndarray" >&2
    cargo test --workspace --features wgpu,ndarray --no-run --message-format=json >"$pack/tests.json"
    for crate in prism_render prism_field prism_gscnet prism_recon; do
        exe=$(grep "\"name\":\"$crate\"" "$pack/tests.json" | grep '"kind":\["lib"\]' | executables | tail -n 1)
        [ -n "$exe" ] || die "package: cargo reported no library test executable for $crate"
        cp "$exe" "$pack/tests/$crate"
    done
    rm -f "$pack/build.json" "$pack/tests.json"
    loader=$(ldconfig -p 2>/dev/null | sed -n 's/.*libvulkan\.so\.1 .*=> \(.*\)/\1/p' | head -n 1)
    [ -n "$loader" ] || die "package: no libvulkan.so.1 here (apt-get install -y libvulkan1)"
    cp -L "$loader" "$pack/lib/libvulkan.so.1"
    # The NVIDIA driver's Vulkan ICD (libGLX_nvidia.so.0) links against glvnd's dispatch library;
    # where the GPU machine lacks it the loader reports "Could not get 'vkCreateInstance' via
    # 'vk_icdGetInstanceProcAddr'" and "Found no drivers" (seen on an H200 image without libglvnd0).
    dispatch=$(ldconfig -p 2>/dev/null | sed -n 's/.*libGLdispatch\.so\.0 .*=> \(.*\)/\1/p' | head -n 1)
    [ -n "$dispatch" ] || die "package: no libGLdispatch.so.0 here (apt-get install -y libglvnd0)"
    cp -L "$dispatch" "$pack/lib/libGLdispatch.so.0"
    if command -v strip >/dev/null; then
        strip --strip-all "$pack"/bin/* "$pack"/tests/*
    fi
    "$pack/bin/prism" --version >/dev/null || die "package: $pack/bin/prism does not start"
    for t in "$pack"/tests/*; do
        "$t" --list >/dev/null || die "package: $t does not start"
    done
    # Each binary also compressed, for transfers with a size limit per file or per call; `run`
    # unpacks what is missing.
    for f in "$pack"/bin/* "$pack"/tests/*; do
        if command -v xz >/dev/null; then
            xz -6 -T0 -c "$f" >"$f.xz.part" && mv "$f.xz.part" "$f.xz"
        else
            gzip -9 -c "$f" >"$f.gz.part" && mv "$f.gz.part" "$f.gz"
        fi
    done
    {
        echo "built $(date -u +%Y-%m-%dT%H:%M:%SZ) on $(uname -m) from $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
        (cd "$pack" && find bin tests lib -type f | sort | while read -r f; do
            echo "$(wc -c <"$f") $f"
        done)
    } >"$pack/MANIFEST.txt"
    echo "gpu-bench: packed $(du -sh "$pack" | cut -f1) into $pack" >&2
}

# Choose the NVIDIA Vulkan driver when the machine has it but no ICD file says so.
vulkan_setup() {
    export LD_LIBRARY_PATH="$pack/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    for d in /usr/share/vulkan/icd.d /etc/vulkan/icd.d; do
        [ -f "$d/nvidia_icd.json" ] && return 0
    done
    own=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    if [ -f "$own" ]; then
        export VK_DRIVER_FILES="$own" VK_ICD_FILENAMES="$own"
        echo "gpu-bench: using the driver's ICD $own" >&2
        return 0
    fi
    if ldconfig -p 2>/dev/null | grep -q libGLX_nvidia.so.0; then
        icd="$out/nvidia_icd.json"
        printf '{"file_format_version":"1.0.0","ICD":{"library_path":"libGLX_nvidia.so.0","api_version":"1.3.0"}}\n' >"$icd"
        export VK_ICD_FILENAMES="$PWD/$icd"
        echo "gpu-bench: no nvidia_icd.json installed; using $icd" >&2
    else
        echo "gpu-bench: no NVIDIA Vulkan driver found; wgpu will take whatever adapter exists" >&2
    fi
}

# step NAME COMMAND...: run, log to OUT/NAME.log, time it, record the exit status.
step() {
    name=$1
    shift
    echo "gpu-bench: $name" >&2
    start=$(date +%s)
    limit=
    [ -n "${GPU_BENCH_LIMIT:-}" ] && limit="timeout $GPU_BENCH_LIMIT"
    if $limit "$@" >"$out/$name.log" 2>&1; then rc=0; else rc=$?; fi
    echo "$name rc=$rc wall_s=$(($(date +%s) - start))" >>"$out/summary.txt"
}

# Binaries that arrived only compressed (.xz: xz, or Python's lzma where xz is missing; .gz).
unpack() {
    for z in "$pack"/bin/*.xz "$pack"/tests/*.xz "$pack"/bin/*.gz "$pack"/tests/*.gz; do
        [ -f "$z" ] || continue
        f=${z%.*}
        [ -x "$f" ] && continue
        case $z in
            *.gz) gzip -dc "$z" >"$f" ;;
            *) if command -v xz >/dev/null; then xz -dc "$z" >"$f"; else
                python3 -c 'import lzma, shutil, sys; shutil.copyfileobj(lzma.open(sys.argv[1]), sys.stdout.buffer)' "$z" >"$f"
            fi ;;
        esac
        chmod +x "$f"
    done
}

# A parity-test step, or a line saying its binary was not brought.
test_step() {
    if [ -x "$pack/tests/$2" ]; then
        step "$1" "$pack/tests/$2" "$3"
    else
        echo "$1 skipped: $pack/tests/$2 not packed" >>"$out/summary.txt"
    fi
}

run() {
    unpack
    [ -x "$pack/bin/prism" ] || die "run: $pack/bin/prism missing (run \`package\` first and bring $pack here)"
    [ -d configs ] && [ -d data ] || die "run: start from the repository root (configs/ and data/ are needed)"
    mkdir -p "$out"
    vulkan_setup
    # Appended, so that steps run by separate calls into one OUT (each with its own limit) share it.
    echo "run $(date -u +%Y-%m-%dT%H:%M:%SZ): ${GPU_BENCH_STEPS:-tests bench scene r2gs 4dsg}" >>"$out/summary.txt"
    command -v nvidia-smi >/dev/null && nvidia-smi -L >>"$out/summary.txt" 2>&1 || true
    prism="$pack/bin/prism"
    case ${GPU_BENCH_BUDGET:-default} in
        default) r2gs=configs/recon/r2gs.yaml fourdsg=configs/recon/4dsg.yaml ;;
        paper) r2gs=configs/recon/r2gs-upstream.yaml fourdsg=configs/recon/4dsg-paper.yaml ;;
        *) die "GPU_BENCH_BUDGET: expected default or paper" ;;
    esac
    for s in ${GPU_BENCH_STEPS:-tests bench scene r2gs 4dsg}; do
        case $s in
            tests)
                test_step tests-render prism_render cube::
                test_step tests-field prism_field wgpu
                test_step tests-gscnet prism_gscnet composed::
                test_step tests-recon prism_recon wgpu
                ;;
            bench)
                step bench-cpu env BENCH_K=100000 BENCH_DETECTOR=512 BENCH_ONLY=affine,voxelize "$pack/bin/render-bench"
                step bench-wgpu env BENCH_DEVICE=wgpu BENCH_K=100000 BENCH_DETECTOR=512 "$pack/bin/render-bench"
                ;;
            scene) step scene "$prism" simulate configs/chest-3mono.yaml --paper-scale -o "$out/chest-paper" ;;
            r2gs) step r2gs "$prism" recon "$r2gs" -s "$out/chest-paper" -o "$out/r2gs" --device wgpu --force ;;
            4dsg) step 4dsg "$prism" recon "$fourdsg" -s "$out/chest-paper" -o "$out/4dsg" --device wgpu --force ;;
            *) die "GPU_BENCH_STEPS: unknown step $s (tests bench scene r2gs 4dsg)" ;;
        esac
    done
    cat "$out/summary.txt"
    for f in "$out"/r2gs/metrics.json "$out"/4dsg/metrics.json; do
        [ -f "$f" ] && echo "$f" && grep -A3 '"mean"' "$f" || true
    done
    ! grep -q 'rc=[1-9]' "$out/summary.txt"
}

case $mode in
    package) package ;;
    run) run ;;
    all) package && run ;;
    *) die "usage: sh scripts/gpu-bench.sh package|run|all [PACK] [OUT]" ;;
esac
