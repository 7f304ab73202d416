#!/usr/bin/env bash
# Smoke run of every fuzz target (fuzz/, docs/robustness.md): about 30 s each from the committed
# seeds, failing on the first crash, hang or runaway allocation. Installs what it needs: the
# nightly toolchain (libFuzzer's sanitizer flags need it) and cargo-fuzz.
#
#   bash scripts/fuzz_smoke.sh                   # every target, 30 s each
#   FUZZ_SECONDS=600 bash scripts/fuzz_smoke.sh can_frames   # one target, longer
#   bash scripts/fuzz_smoke.sh slcan_lines can_frames          # the CAN and SLCAN decoders
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

if ! rustup toolchain list | grep -q '^nightly'; then
    rustup toolchain install nightly --profile minimal
fi
if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi

seconds="${FUZZ_SECONDS:-30}"
if [ "$#" -gt 0 ]; then
    targets="$*"
else
    targets="$(cargo +nightly fuzz list)"
fi

cargo +nightly fuzz build
for target in $targets; do
    echo "== fuzz $target for ${seconds}s"
    # New inputs go to fuzz/corpus/ (ignored by git); the seeds stay as committed.
    # A target without committed seeds (trajectory_batch) starts from an empty directory:
    # libFuzzer refuses a corpus directory that does not exist.
    mkdir -p "fuzz/corpus/$target" "fuzz/seeds/$target"
    # -timeout: one input may take 10 s at most (a hang); -rss_limit_mb: 2 GB at most (an
    # unbounded allocation). Input length: libFuzzer's default, 4 KiB or the largest seed.
    cargo +nightly fuzz run "$target" "fuzz/corpus/$target" "fuzz/seeds/$target" -- \
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1
done
