#!/usr/bin/env bash
# Worst-case stack and instruction count of one decision (`Policy::act`) on a weights file:
# the stack by painting (runtime/examples/stack_probe.rs), the instructions by callgrind for
# three very different inputs per kernel (N decisions minus 0, divided by N). Equal counts
# across inputs show the time does not depend on the data.
#
#   bash tools/stack_time_bound.sh [WEIGHTS.wlw] [N]
#
# Needs valgrind for the instruction counts (`apt-get install valgrind`).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
weights="${1:-$root/weights/policy.wlw}"
n="${2:-100}"
(cd "$root" && cargo build --quiet --workspace --release --example stack_probe)
bin="${CARGO_TARGET_DIR:-$root/target}/release/examples/stack_probe"
"$bin" "$weights"
if ! command -v valgrind >/dev/null; then
    echo "stack_time_bound: valgrind not found, instruction counts skipped" >&2
    exit 0
fi
# shellcheck source=tools/callgrind_lib.sh
source "$root/tools/callgrind_lib.sh"
printf '%-8s %-8s %14s\n' kernel input instr/decision
for kernel in $kernels; do
    for input in zeros ramp extreme; do
        base="$(refs "$weights" "$input" 0 "$kernel")"
        full="$(refs "$weights" "$input" "$n" "$kernel")"
        printf '%-8s %-8s %14s\n' "$kernel" "$input" "$(( (full - base) / n ))"
    done
done
