#!/usr/bin/env bash
# The planner's speed against another version of it, on the same scenes, in one run.
#
#     tools/planner_speed.sh [OLD_REV] [STRIDE] [SCENARIOS] [BUDGET]
#
# Builds sim/examples/plan_file.rs (one thread, `wheelleg plan`'s searches and JSON fields)
# twice: against this tree's planner ("new") and against the planner of git revision OLD_REV
# (default: main; checked out in a detached worktree, the example copied in). Then plans every
# STRIDE-th scene of SCENARIOS (default: every 10th of eval/heldout-complex-s1000000.json) at
# BUDGET expansions per search (default 5,000, as the held-out plan pass), one process per scene
# and version, the two versions alternating (old first on even scenes, new first on odd), and
# reports the CPU-seconds (user + system) of each version over the sample and their ratio, and
# whether every result line (verdict, steps, shortest, expansions) is identical.
#
# Results, timings and the old tree's build go to target/planner-speed/ (PLANNER_SPEED_DIR), this
# tree's build to CARGO_TARGET_DIR (default target/). Builds run niced with JOBS (default 1)
# jobs, for a shared machine.
set -euo pipefail

root=$(git rev-parse --show-toplevel)
old_rev=${1:-main}
stride=${2:-10}
scenarios=${3:-$root/eval/heldout-complex-s1000000.json}
budget=${4:-5000}
out=${PLANNER_SPEED_DIR:-$root/target/planner-speed}
target=${CARGO_TARGET_DIR:-$root/target}
jobs=${JOBS:-1}
mkdir -p "$out"

# shellcheck source=tools/old_tree.sh
source "$root/tools/old_tree.sh"
old_tree "$root" "$out" "$old_rev"
cp "$root/sim/examples/plan_file.rs" "$old_src/sim/examples/plan_file.rs"

build() { # tree, target dir, name
    (cd "$1" && CARGO_TARGET_DIR=$2 nice -n 5 \
        cargo build --quiet --workspace --release --example plan_file -j"$jobs")
    cp "$2/release/examples/plan_file" "$out/plan_file.$3"
}
echo "building the old planner ($(git -C "$old_src" rev-parse --short HEAD)) and the new one ($(git -C "$root" rev-parse --short HEAD)$(git -C "$root" diff --quiet HEAD -- sim || echo ', with changes'))"
# Two target dirs: cargo names a workspace member's artifacts by its path relative to the
# workspace, so the two trees' builds would take each other's for fresh.
build "$old_src" "$out/old-target" old
build "$root" "$target" new
if cmp -s "$out/plan_file.old" "$out/plan_file.new"; then
    echo "the two builds are the same binary" >&2
    exit 1
fi

count=$(python3 -c 'import json,sys; print(len(json.load(open(sys.argv[1]))["scenarios"]))' "$scenarios")
: >"$out/old.jsonl"
: >"$out/new.jsonl"
: >"$out/times.tsv"
run() { # version, scene index; appends the result line, prints the CPU-seconds
    /usr/bin/time -f "%U %S" -o "$out/time.$1" \
        "$out/plan_file.$1" "$scenarios" "$budget" "$count" "$2" >>"$out/$1.jsonl"
    awk '{ printf "%.2f", $1 + $2 }' "$out/time.$1"
}
old_total=0
new_total=0
scenes=0
for ((i = 0; i < count; i += stride)); do
    if ((scenes % 2 == 0)); then
        old_s=$(run old "$i")
        new_s=$(run new "$i")
    else
        new_s=$(run new "$i")
        old_s=$(run old "$i")
    fi
    scenes=$((scenes + 1))
    old_total=$(awk -v a="$old_total" -v b="$old_s" 'BEGIN { print a + b }')
    new_total=$(awk -v a="$new_total" -v b="$new_s" 'BEGIN { print a + b }')
    printf '%d\t%s\t%s\n' "$i" "$old_s" "$new_s" >>"$out/times.tsv"
    printf 'scene %4d: old %7.2f s, new %7.2f s (totals %.1f / %.1f s)\n' \
        "$i" "$old_s" "$new_s" "$old_total" "$new_total"
done
echo "scenes: $scenes (every ${stride}th of $scenarios, budget $budget)"
echo "CPU-seconds: old $old_total, new $new_total, ratio $(awk -v a="$old_total" -v b="$new_total" 'BEGIN { printf "%.2f", a / b }')"
status=0
if cmp -s "$out/old.jsonl" "$out/new.jsonl"; then
    echo "results: old and new identical ($scenes scenes)"
else
    echo "results: old and new DIFFER"
    diff "$out/old.jsonl" "$out/new.jsonl" | head -20
    status=1
fi
# The stored plan pass of the scene set, if there is one (`wheelleg plan --json` of it).
stored=${scenarios%.json}.plan.json
if [ -f "$stored" ]; then
    python3 - "$stored" "$out/new.jsonl" <<'PY' || status=1
import json, sys
stored = {r["name"]: r for r in json.load(open(sys.argv[1]))["results"]}
new = [json.loads(line) for line in open(sys.argv[2])]
differ = [r for r in new if stored.get(r["name"]) != r]
print(f"results: new against {sys.argv[1]}: {len(new) - len(differ)} of {len(new)} identical")
for r in differ[:10]:
    print(f"  {r['name']}: stored {stored.get(r['name'])}, new {r}")
sys.exit(1 if differ else 0)
PY
fi
exit $status
