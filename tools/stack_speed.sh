#!/usr/bin/env bash
# The full decision stack's cost against another version of it, on the same episodes, in one
# run: what the look-ahead and its searches cost per 1,000 held-out episodes.
#
#     tools/stack_speed.sh [OLD_REV] [CHUNKS] [RUN] [SCENARIOS] [POLICY]
#
# Builds `wheelleg` twice: this tree's ("new") and git revision OLD_REV's (default: main;
# checked out in a detached worktree). Cuts SCENARIOS (default: the 1,000 held-out complex
# scenes) into CHUNKS files (default 10), and runs `wheelleg eval --stack full` of POLICY
# (default: weights/policy.wlw, the same file for both) on the first RUN chunks (default: all;
# fewer for a sample, the per-1,000 figures scaled from it) with each version, the two
# alternating (old first on even chunks, new first on odd) so that a machine's changing load
# falls on both alike. Reports the CPU-seconds (user + system) and wall seconds of each
# version over all episodes, per 1,000 episodes, their ratio, and whether the episodes' results
# (the JSON of every chunk) are identical.
#
# EVAL_ARGS are added to every `eval` (e.g. "--lookahead-search 0 --last-metres 0": the stack
# without its searches, the rollouts alone).
#
# Results, timings and the old tree's build go to target/stack-speed/ (STACK_SPEED_DIR); this
# tree's build to CARGO_TARGET_DIR (default target/). Builds run niced with JOBS (default 1)
# jobs, for a shared machine.
set -euo pipefail

root=$(git rev-parse --show-toplevel)
old_rev=${1:-main}
chunks=${2:-10}
run_chunks=${3:-$chunks}
scenarios=${4:-$root/eval/heldout-complex-s1000000.json}
policy=${5:-$root/weights/policy.wlw}
out=${STACK_SPEED_DIR:-$root/target/stack-speed}
target=${CARGO_TARGET_DIR:-$root/target}
jobs=${JOBS:-1}
mkdir -p "$out"

# shellcheck source=tools/old_tree.sh
source "$root/tools/old_tree.sh"
old_tree "$root" "$out" "$old_rev"

build() { # tree, target dir, name
    (cd "$1" && CARGO_TARGET_DIR=$2 nice -n 5 \
        cargo build --quiet --release --bin wheelleg -j"$jobs")
    cp "$2/release/wheelleg" "$out/wheelleg.$3"
}
echo "building the old stack ($(git -C "$old_src" rev-parse --short HEAD)) and the new one ($(git -C "$root" rev-parse --short HEAD)$(git -C "$root" diff --quiet HEAD -- sim stack src || echo ', with changes'))"
# Two target dirs: cargo names a workspace member's artifacts by its path relative to the
# workspace, so the two trees' builds would take each other's for fresh.
build "$old_src" "$out/old-target" old
build "$root" "$target" new

# The chunks, each a scenario file of its own, in the order of SCENARIOS.
python3 - "$scenarios" "$chunks" "$out" <<'PY'
import json, sys
whole = json.load(open(sys.argv[1]))
n = int(sys.argv[2])
scenes = whole["scenarios"]
size = -(-len(scenes) // n)
for k in range(n):
    part = dict(whole, scenarios=scenes[k * size:(k + 1) * size])
    json.dump(part, open(f"{sys.argv[3]}/chunk-{k}.json", "w"))
PY

run() { # version, chunk; writes the chunk's JSON, prints "CPU-seconds wall-seconds"
    /usr/bin/time -f "%U %S %e" -o "$out/time.$1" \
        "$out/wheelleg.$1" eval --policy "$policy" --scenarios "$out/chunk-$2.json" \
        --stack full --max-expansions 0 --json ${EVAL_ARGS:-} >"$out/$1.chunk-$2.json"
    awk '{ printf "%.2f %.2f\n", $1 + $2, $3 }' "$out/time.$1"
}
old_cpu=0 new_cpu=0 old_wall=0 new_wall=0
: >"$out/times.tsv"
for ((k = 0; k < run_chunks; k++)); do
    if ((k % 2 == 0)); then
        read -r oc ow < <(run old "$k")
        read -r nc nw < <(run new "$k")
    else
        read -r nc nw < <(run new "$k")
        read -r oc ow < <(run old "$k")
    fi
    old_cpu=$(awk -v a="$old_cpu" -v b="$oc" 'BEGIN { print a + b }')
    new_cpu=$(awk -v a="$new_cpu" -v b="$nc" 'BEGIN { print a + b }')
    old_wall=$(awk -v a="$old_wall" -v b="$ow" 'BEGIN { print a + b }')
    new_wall=$(awk -v a="$new_wall" -v b="$nw" 'BEGIN { print a + b }')
    printf '%d\t%s\t%s\t%s\t%s\n' "$k" "$oc" "$nc" "$ow" "$nw" >>"$out/times.tsv"
    printf 'chunk %2d: old %7.1f CPU-s %6.1f s, new %7.1f CPU-s %6.1f s\n' "$k" "$oc" "$ow" "$nc" "$nw"
done
episodes=$(python3 -c 'import json,sys; print(sum(len(json.load(open(f"{sys.argv[1]}/chunk-{k}.json"))["scenarios"]) for k in range(int(sys.argv[2]))))' "$out" "$run_chunks")
per() { awk -v t="$1" -v n="$episodes" 'BEGIN { printf "%.0f", t * 1000 / n }'; }
echo "episodes: $episodes (the first $run_chunks of $chunks chunks of $scenarios, $(basename "$policy"), --stack full ${EVAL_ARGS:-})"
echo "CPU-seconds: old $old_cpu, new $new_cpu, ratio $(awk -v a="$old_cpu" -v b="$new_cpu" 'BEGIN { printf "%.2f", a / b }')"
echo "per 1,000 episodes: old $(per "$old_cpu") CPU-s ($(per "$old_wall") s wall), new $(per "$new_cpu") CPU-s ($(per "$new_wall") s wall)"
status=0
for ((k = 0; k < run_chunks; k++)); do
    if ! cmp -s "$out/old.chunk-$k.json" "$out/new.chunk-$k.json"; then
        echo "results: chunk $k DIFFERS"
        status=1
    fi
done
((status == 0)) && echo "results: old and new identical (every chunk's JSON)"
exit $status
