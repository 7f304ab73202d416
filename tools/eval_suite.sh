#!/usr/bin/env bash
# One markdown table row per policy: the held-out complex set (success, collision-free, mean
# path, ratio to the planner's shortest) and 200 held-out scenes of each leg behaviour
# (success / collision-free), the figures of docs/results.md.
#
#   tools/eval_suite.sh [--stochastic|--argmax|--guard|--guard-arrival|--guard-fine-arrival] CKPT_OR_WLW...
#
# --guard-arrival: the collision guard (on the policy's 5 cm map) and the arrival rule.
# --guard-fine-arrival: the guard on the 1 cm map and the arrival rule, as `wheelleg demo` runs
# by default.
#
# WHEELLEG names the binary (default: target/release/wheelleg). Seeds: the committed held-out
# complex set (generator seed 1,000,000) and generated behaviour scenes at seed 1,000,000, never
# used in training.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${WHEELLEG:-target/release/wheelleg}
rule=()
if [[ "${1:-}" == --stochastic || "${1:-}" == --argmax || "${1:-}" == --guard ]]; then
    rule=("$1")
    shift
elif [[ "${1:-}" == --guard-arrival ]]; then
    rule=(--guard --arrival)
    shift
elif [[ "${1:-}" == --guard-fine-arrival ]]; then
    rule=(--guard --guard-map fine --arrival)
    shift
fi
[[ $# -gt 0 ]] || { echo "usage: $0 [--stochastic|--argmax|--guard|--guard-arrival|--guard-fine-arrival] POLICY..." >&2; exit 2; }
heldout=eval/heldout-complex-s1000000.json
plan=eval/heldout-complex-s1000000.plan.json
summary() {
    python3 -c '
import json, sys
r = json.load(sys.stdin)
pct = lambda x: "%.1f%%" % (100 * x)
fields = [pct(r["success_rate"]), pct(r["collision_free_rate"])]
if sys.argv[1] == "full":
    fields.append("-" if r["mean_steps"] is None else "%.1f" % r["mean_steps"])
    ratio = r["steps_vs_shortest"]
    fields.append("-" if ratio is None else "%.3fx" % ratio)
    print(" | ".join(fields), end="")
else:
    print(" / ".join(fields), end="")
' "$1"
}
echo "| policy | rule | complex success | collision-free | mean path | vs shortest | around | lift | spread | squeeze |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for policy in "$@"; do
    row="| $policy | ${rule[*]:-untried} | "
    row+=$("$bin" eval --policy "$policy" --scenarios "$heldout" --planner-results "$plan" \
        "${rule[@]}" --json | summary full)
    for kind in around lift spread squeeze; do
        row+=" | "
        row+=$("$bin" eval --policy "$policy" --generated 200 --kind "$kind" --seed 1000000 \
            --planner-expansions 0 "${rule[@]}" --json | summary short)
    done
    echo "$row |"
done
