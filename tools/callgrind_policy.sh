#!/usr/bin/env bash
# Instructions per decision of the int8 policy runtime (each kernel this CPU runs) and of the
# trainer's float forward, counted by callgrind: a run of N decisions minus a run of 0 (which
# leaves out start-up, network construction, quantization and loading), divided by N.
#
#   bash tools/callgrind_policy.sh [N] [WEIGHTS.wlw]
#
# N defaults to 200 (20 for the float forward, which is 30x slower under valgrind). Without a
# weights file the default network with seeded random weights is used (the instruction count
# does not depend on the weight values: no kernel branches on data). Needs valgrind
# (`apt-get install valgrind`).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
n="${1:-200}"
weights="${2:-}"
if ! command -v valgrind >/dev/null; then
    echo "callgrind_policy: valgrind not found (apt-get install valgrind)" >&2
    exit 1
fi
(cd "$root" && cargo build --quiet --workspace --release --example decisions)
bin="${CARGO_TARGET_DIR:-$root/target}/release/examples/decisions"
# shellcheck source=tools/callgrind_lib.sh
source "$root/tools/callgrind_lib.sh"
printf '%-8s %12s %16s\n' kernel decisions instr/decision
for kernel in $kernels f32; do
    count="$n"
    [[ "$kernel" == f32 ]] && count=$(( n / 10 > 0 ? n / 10 : 1 ))
    # shellcheck disable=SC2086
    base="$(refs "$kernel" 0 $weights)"
    # shellcheck disable=SC2086
    full="$(refs "$kernel" "$count" $weights)"
    printf '%-8s %12d %16d\n' "$kernel" "$count" $(( (full - base) / count ))
done
