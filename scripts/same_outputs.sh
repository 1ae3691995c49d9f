#!/usr/bin/env bash
# Do this checkout's `pdr run` and `pdr discover` give the same bytes as another commit's on the shipped raw/?
#
#   scripts/same_outputs.sh [REF [NEW]]   (REF: a commit or branch, default main; NEW: a commit or tree,
#                                          default this checkout as it is, e.g. `git merge-tree --write-tree`)
#
# For refactors that must not change behaviour.  REF's tree (and NEW's) is exported (git archive) to a
# temporary folder and run with this checkout's .venv (PYTHONPATH puts that package first; its numba
# kernels compile on the first run, a minute or two).  Both sides read NEW's raw/ and write to their
# own processed/; every file is then compared by scripts/same_outputs.py: byte for byte, except the .rrd files (Rerun stores its
# own ids and times: compared with `rerun rrd compare` instead), stamp.json (it holds the code version, a digest
# of the code itself) and the wall time `pdr discover --json` reports.
# A branch behind main: compare with its fork point (REF = `git merge-base main HEAD`), or main with
# the merge (`scripts/same_outputs.sh main $(git merge-tree --write-tree main HEAD)`).
# Exit status 0 when everything matches, 1 otherwise.  Nothing in this checkout is written.
set -euo pipefail

ref=${1:-main}
here=$(git rev-parse --show-toplevel)
py="$here/.venv/bin/python"
work=$(mktemp -d "${TMPDIR:-/tmp}/same-outputs.XXXXXX")
[ -n "${KEEP:-}" ] || trap 'rm -rf "$work"' EXIT    # KEEP=1: leave the outputs for a look
mkdir -p "$work/ref"
git -C "$here" archive "$ref" pipeline schemas | tar -x -C "$work/ref"
new_src=$here
if [ -n "${2:-}" ]; then
    new_src="$work/new"
    mkdir -p "$new_src"
    git -C "$here" archive "$2" pipeline schemas raw | tar -x -C "$new_src"
fi

pdr() {   # pdr SRC_TREE ARGS...: the command line of the package found in SRC_TREE
    local src=$1
    shift
    PYTHONPATH="$src" PYTHONDONTWRITEBYTECODE=1 "$py" -c 'import sys; from pipeline.cli import main; sys.argv[0] = "pdr"; main()' "$@"
}

for side in ref new; do
    src=$([ "$side" = ref ] && echo "$work/ref" || echo "$new_src")
    out="$work/out-$side"
    echo "same_outputs: $side ($([ "$side" = ref ] && echo "$ref" || echo "${2:-this checkout}")) ..." >&2
    (cd "$new_src" && pdr "$src" run --raw raw --processed "$out" --force -j 2 >/dev/null 2>&1)
    mkdir -p "$out/discovery"
    for csv in "$new_src"/raw/*.csv; do
        (cd "$new_src" && pdr "$src" discover "$csv" --processed "$out" --out "$out/discovery/$(basename "$csv" .csv)" \
            --json > "$out/discovery/$(basename "$csv" .csv).stdout.json") || true
    done
    find "$out" -name stamp.json -exec sed -i '/"code_version"/d' {} +
    sed -i '/^  "seconds": /d' "$out"/discovery/*.stdout.json              # the wall time discovery took
    rm -f "$out/.pdr.lock"
done

# byte for byte, stamps aside; every .rrd by `rerun rrd compare` (Rerun stores its own ids and times)
PYTHONPATH="$here" "$py" "$here/scripts/same_outputs.py" "$work/out-ref" "$work/out-new"
