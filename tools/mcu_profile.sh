#!/usr/bin/env bash
# Where the controller's inference spends its instructions: the check image run in QEMU
# (mps2-an386, -icount shift=0) with a TCG plugin counting every executed instruction by
# address (tools/qemu_insn_counts/insn_counts.c), then the counts attributed to source lines
# through the image's debug information, per decision. The check image is built with
# WHEELLEG_CHECK_FAST_ONLY=1, which leaves out the scalar kernel's reference run, so that only
# the DSP kernel is counted; the plain build is restored afterwards.
#
#   bash scripts/mcu.sh            # first: writes the vectors to controller/target/mcu-check
#   bash tools/mcu_profile.sh [ROWS]
#
# Needs gcc (to build the plugin), qemu-system-arm with plugin support and llvm-addr2line.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
rows="${1:-30}"
work="$root/controller/target/mcu-check"
out="$root/controller/target/mcu-profile"
if [ ! -f "$work/decisions.bin" ]; then
    echo "mcu_profile: no vectors in $work: run scripts/mcu.sh first" >&2
    exit 1
fi
mkdir -p "$out"
gcc -O2 -shared -fPIC -o "$out/libinsn_counts.so" "$root/tools/qemu_insn_counts/insn_counts.c"
elf="$root/controller/target/thumbv7em-none-eabihf/release/wheelleg-controller-check"
(cd "$root/controller" && WHEELLEG_CHECK_FAST_ONLY=1 nice -n 19 cargo +nightly build --quiet \
    --release -j 1 --bin wheelleg-controller-check)
cp "$elf" "$out/wheelleg-controller-check"
(cd "$root/controller" && nice -n 19 cargo +nightly build --quiet --release -j 1 \
    --bin wheelleg-controller-check)
run="$out/run"
rm -rf "$run"
mkdir -p "$run"
cp "$work"/decisions.bin "$work"/episode.bin "$run"/
(cd "$run" && timeout 900 nice -n 19 qemu-system-arm -machine mps2-an386 -nographic \
    -semihosting-config enable=on,target=native -icount shift=0 \
    -plugin "$out/libinsn_counts.so,arg=out=$out/counts.txt" \
    -kernel "$out/wheelleg-controller-check") >"$out/console.txt" 2>&1
# Every inference of the run: the decisions and the episode's.
decisions=$(grep -o ' decisions=[0-9]*' "$out/console.txt" | head -1 | cut -d= -f2)
record_bytes=$(( $(stat -c %s "$run/decisions.out") / decisions ))
inferences=$(( decisions + $(stat -c %s "$run/episode.decisions.out") / record_bytes ))
echo "mcu_profile: $inferences inferences ($decisions decisions and the episode's), counts in $out/counts.txt" >&2
python3 "$root/tools/qemu_insn_counts/attribute.py" "$out/wheelleg-controller-check" \
    "$out/counts.txt" "$inferences" "$rows"
