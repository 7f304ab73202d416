#!/usr/bin/env bash
# A policy on the validation sets (seed 3,000,000; docs/results.md, "Held-out sets and rules"):
# 500 composed, 500 complex and 200 each of lift, spread and squeeze, the 1,600 that checkpoints
# and expert-iteration rounds are chosen by. Success only (no planner), so a policy takes minutes.
#
#   bash scripts/validate.sh POLICY [STACK]      # STACK: robot (default), policy or full
#
# Prints one JSON line per set and a last line with the total; the sets' scenes are generated
# once under target/validation/.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

policy="${1:?usage: scripts/validate.sh POLICY [STACK]}"
stack="${2:-robot}"
seed=3000000
bin=target/release/wheelleg
[ -x "$bin" ] || cargo build --quiet --workspace --release --bins --examples

sets=target/validation
mkdir -p "$sets"
composed="$sets/composed-s$seed.json"
if [ ! -f "$composed" ]; then
    "$bin" generate --kind composed --count 500 --seed "$seed" --out "$composed.tmp" >/dev/null
    mv "$composed.tmp" "$composed"
fi

one() {
    local name="$1"
    shift
    "$bin" eval --policy "$policy" --stack "$stack" --max-expansions 0 --json "$@" |
        python3 -c '
import json, sys
result = json.load(sys.stdin)
scenes = result["scenarios"]
print(json.dumps({"set": sys.argv[1], "scenes": len(scenes),
                  "success": sum(s["success"] for s in scenes),
                  "collision_free": sum(s["success"] and s["collision_free"] for s in scenes)}))
' "$name"
}
results="$(
    one composed --scenarios "$composed"
    one complex --generated 500 --kind complex --seed "$seed"
    for kind in lift spread squeeze; do
        one "$kind" --generated 200 --kind "$kind" --seed "$seed"
    done
)"
echo "$results"
python3 - "$policy" "$stack" "$results" <<'EOF'
import json, sys
policy, stack, lines = sys.argv[1], sys.argv[2], sys.argv[3].splitlines()
rows = [json.loads(l) for l in lines]
n = sum(r["scenes"] for r in rows)
ok = sum(r["success"] for r in rows)
free = sum(r["collision_free"] for r in rows)
print(json.dumps({"set": "all", "policy": policy, "stack": stack, "scenes": n, "success": ok,
                  "collision_free": free, "success_rate": round(ok / n, 4)}))
EOF
