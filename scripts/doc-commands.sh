#!/bin/sh
# Run the commands of the documentation: every ```sh block of README.md and docs/*.md.
#
#   sh scripts/doc-commands.sh [PRISM_BINARY] [PAGE ...]
#
# PRISM_BINARY (default target/release/prism) is what `prism` means in the blocks: a shim
# directory holding `prism` is put first on PATH. PAGE (e.g. docs/naf.md) runs only those pages.
#
# Where they run: a scratch repository root, $DOC_COMMANDS_DIR/root (default
# runs/doc-commands/root, wiped first), which links every top-level entry of the repository except
# runs/, results/ and scenes/. The blocks therefore see configs/, scripts/, data/, … at the same
# relative paths as in the repository root, while everything they write under runs/ (or results/)
# lands in the scratch root and clobbers nothing. Logs: $DOC_COMMANDS_DIR/logs/.
#
# Order and dependencies: the script first runs a prelude, `prism simulate configs/smoke.yaml -o
# runs/smoke/scene` (the smoke scene every page uses), then README.md, then docs/*.md in file-name
# order. Blocks of one page run in order and may use what earlier blocks of the same page wrote;
# no page depends on another page, only on the prelude's scene. Each block runs as one
# `sh -e -x` script from the scratch root; the first failing block stops the script (exit 1),
# named by file and line, with the end of its log.
#
# Skipping a block: the line right before its opening fence (blank lines aside) is an HTML comment
# starting `<!-- not run by doc-commands` (e.g. `<!-- not run by doc-commands: set-up -->`). The
# README's two set-up blocks (the main job, which builds with cargo, and the test command) carry
# it. Commands meant to be read, not run (long suites, paper scale, files a clone lacks) belong in
# ```text blocks instead, which are never run.
set -eu
here=$(cd "$(dirname "$0")/.." && pwd)
cd "$here"
prism=${1:-target/release/prism}
[ $# -gt 0 ] && shift
[ -x "$prism" ] || { echo "doc-commands: $prism is not an executable (build it: cargo build --release)" >&2; exit 2; }
prism=$(realpath "$prism")

work=${DOC_COMMANDS_DIR:-runs/doc-commands}
case "$work" in /*) ;; *) work=$here/$work ;; esac
# Wiped first, but only a directory this script made (it leaves a .doc-commands mark there).
if [ -e "$work" ] && [ ! -e "$work/.doc-commands" ] && [ -n "$(ls -A "$work" 2>/dev/null)" ]; then
    echo "doc-commands: $work exists and was not made by this script; not wiping it" >&2
    exit 2
fi
rm -rf "$work"
mkdir -p "$work" && : > "$work/.doc-commands"
mkdir -p "$work/bin" "$work/root" "$work/blocks" "$work/logs"
printf '#!/bin/sh\nexec "%s" "$@"\n' "$prism" > "$work/bin/prism"
chmod +x "$work/bin/prism"
for entry in "$here"/* "$here"/.[!.]*; do
    [ -e "$entry" ] || continue
    case "${entry##*/}" in runs | results | scenes) continue ;; esac
    ln -s "$entry" "$work/root/${entry##*/}"
done

# The pages, in order.
if [ $# -gt 0 ]; then
    pages="$*"
else
    pages="README.md $(LC_ALL=C ls docs/*.md | tr '\n' ' ')"
fi

# Extract the blocks: blocks/NNNN.sh, and one line per block in blocks/index
# ("NNNN FILE LINE run|skip").
n=0
for page in $pages; do
    [ -f "$page" ] || { echo "doc-commands: no page $page" >&2; exit 2; }
    n=$(awk -v page="$page" -v dir="$work/blocks" -v n="$n" '
        function flush() { close(file) }
        inblock && /^```[ \t]*$/ { inblock = 0; flush(); prev = $0; next }
        inblock { print > file; next }
        /^```sh[ \t]*$/ {
            n++; inblock = 1; file = sprintf("%s/%04d.sh", dir, n)
            mode = (prev ~ /^<!-- not run by doc-commands/) ? "skip" : "run"
            printf "%04d %s %d %s\n", n, page, NR, mode >> (dir "/index")
            printf "" > file
            prev = $0
            next
        }
        /[^ \t]/ { prev = $0 }
        END {
            if (inblock) { printf "%s:%d: a ```sh block is never closed\n", page, NR > "/dev/stderr"; exit 1 }
            print n
        }' "$page")
done
[ -f "$work/blocks/index" ] || { echo "doc-commands: no \`\`\`sh blocks in $pages" >&2; exit 2; }

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }
export PATH="$work/bin:$PATH"
start=$(now)

# The prelude: the smoke scene every page starts from.
printf 'prism simulate configs/smoke.yaml -o runs/smoke/scene\n' > "$work/blocks/prelude.sh"
t0=$(now)
if ! (cd "$work/root" && sh -e -x "$work/blocks/prelude.sh") < /dev/null > "$work/logs/prelude.log" 2>&1; then
    echo "FAILED: the prelude (prism simulate configs/smoke.yaml -o runs/smoke/scene)" >&2
    tail -n 30 "$work/logs/prelude.log" >&2
    exit 1
fi
echo "ok    prelude: runs/smoke/scene ($(elapsed "$t0" "$(now)") s)"

ran=0; skipped=0
while read -r id file line mode; do
    if [ "$mode" = skip ]; then
        echo "skip  $file:$line (marked not run)"
        skipped=$((skipped + 1))
        continue
    fi
    log="$work/logs/$id.log"
    t0=$(now)
    if ! (cd "$work/root" && sh -e -x "$work/blocks/$id.sh") < /dev/null > "$log" 2>&1; then
        echo "FAILED: the \`\`\`sh block at $file:$line (after $(elapsed "$t0" "$(now)") s; log $log):" >&2
        tail -n 30 "$log" >&2
        exit 1
    fi
    ran=$((ran + 1))
    echo "ok    $file:$line ($(elapsed "$t0" "$(now)") s)"
done < "$work/blocks/index"
echo "doc-commands: $ran blocks ran, $skipped skipped, all passed in $(elapsed "$start" "$(now)") s (prism: $prism)"
