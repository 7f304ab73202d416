#!/usr/bin/env bash
# Builds and runs the no_std proof: a #![no_std] #![no_main] binary linking wheelleg-runtime
# with its own panic handler and no allocator. Fails if the build fails (std or alloc linked),
# if the binary contains std or allocator symbols, or if its decision differs from the host's.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
out="$here/target/check"
mkdir -p "$out"

# A weights file and the decision the host takes on the check's observation.
# The workspace's feature set, as scripts/test.sh builds it: the trainer's own set rebuilds burn.
(cd "$root" && cargo build --quiet --workspace --release --bins --examples)
expected="$("$root/target/release/examples/random_policy" "$out/policy.wlw")"

# The binary itself (its own workspace, panic = "abort").
(cd "$here" && CARGO_TARGET_DIR="$here/target" WHEELLEG_POLICY="$out/policy.wlw" cargo build --quiet --release)
binary="$here/target/release/wheelleg-nostd-check"

# Belt and braces: no std, no allocator shims in what was linked.
if nm --demangle "$binary" | grep -E ' (std::|alloc::alloc|__rust_alloc|__rdl_alloc|__rg_alloc)' ; then
    echo "nostd-check: std or allocator symbols linked" >&2
    exit 1
fi

actual="$("$binary")"
if [[ "$actual" != "$expected" ]]; then
    echo "nostd-check: no_std decision $actual != host decision $expected" >&2
    exit 1
fi
echo "nostd-check: no_std binary linked without std/alloc and decided actions $actual (first, then after a refusal, then with the collision guard and its level; host agrees), SLCAN line round trip ok"
