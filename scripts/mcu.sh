#!/usr/bin/env bash
# The controller firmware (controller/) checked and measured in QEMU's mps2-an386 (Cortex-M4F):
#   1. installs the embedded toolchain if needed (scripts/embedded-toolchain.sh);
#   2. writes the test vectors with the host's runtime (examples/mcu_vectors.rs): at least
#      1,000 observations of held-out episodes with the host's decision on each, and one
#      held-out episode through the host's closed loop with every CAN frame, period by period;
#   3. builds the firmware's two images, the production image (wheelleg-controller: what
#      flash is measured on) and the check image (wheelleg-controller-check: the same code
#      with the check harness), and runs the check image in QEMU with deterministic
#      instruction counting (-icount shift=0: one instruction per virtual nanosecond);
#   4. compares the firmware's decisions and frames with the host's, byte for byte;
#   5. reports sizes from the linked ELFs and the counts the check image measured;
#   6. runs the production image in the loop for one held-out episode (the world and the
#      simulated motors on the host, the firmware in QEMU on its observation link and SLCAN
#      adapter link), where its own stack is measured: QEMU's loader paints the free RAM and
#      its monitor saves it at the end. RAM is the production image's statics and that stack.
#      The fault tests and the equivalence with the host are scripts/hil.sh's.
#
#   bash scripts/mcu.sh            human-readable report
#   bash scripts/mcu.sh --json     one JSON object on stdout (the rest on stderr)
#
# Exits non-zero when anything differs from the host, fails to build or run, or the
# production image is over the budget (512 KiB flash, 128 KiB RAM of the reference part, an
# STM32G474-class Cortex-M4F at 170 MHz: "fits_budget"); docs/controller.md says where the
# bytes go and why the reference part is not the 128 KiB / 32 KiB G431.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
root="$(pwd)"

json=false
[ "${1:-}" = "--json" ] && json=true
log() { echo "mcu: $*" >&2; }

FLASH_BUDGET=$((512 * 1024))
RAM_BUDGET=$((128 * 1024))
decisions="${MCU_DECISIONS:-1000}"

bash scripts/embedded-toolchain.sh >&2

work="$root/controller/target/mcu-check"
rm -rf "$work"
mkdir -p "$work"

log "writing test vectors (host runtime, held-out scenes)"
# The workspace's feature set, as scripts/test.sh builds it: a package's own set rebuilds burn.
nice -n 10 cargo build --quiet --workspace --release --bins --examples >&2
vectors_json="$("$root/target/release/examples/mcu_vectors" vectors "$work" --decisions "$decisions")"
log "vectors: $vectors_json"

log "building the firmware (thumbv7em-none-eabihf)"
(cd controller && nice -n 10 cargo +nightly build --quiet --release) >&2
elf="$root/controller/target/thumbv7em-none-eabihf/release/wheelleg-controller"
check_elf="$root/controller/target/thumbv7em-none-eabihf/release/wheelleg-controller-check"

log "running it in QEMU (mps2-an386, -icount shift=0)"
console="$work/console.txt"
set +e
(cd "$work" && timeout 600 nice -n 10 qemu-system-arm -machine mps2-an386 -nographic \
    -semihosting-config enable=on,target=native -icount shift=0 -kernel "$check_elf") >"$console" 2>&1
status=$?
set -e
cat "$console" >&2
if [ "$status" -ne 0 ]; then
    log "error: the firmware exited with status $status"
    exit 1
fi

field() {
    local value
    value="$(grep -o "$1=[0-9]*" "$console" | head -1 | cut -d= -f2)"
    if [ -z "$value" ]; then
        log "error: the firmware reported no $1"
        exit 1
    fi
    echo "$value"
}

match=true
for pair in decisions.out:decisions.expected episode.decisions.out:episode.decisions.expected \
    episode.frames.out:episode.frames.expected; do
    actual="$work/${pair%%:*}"
    expected="$work/${pair##*:}"
    if cmp -s "$actual" "$expected"; then
        log "${pair%%:*}: identical to the host's ($(stat -c %s "$expected") bytes)"
    else
        log "error: ${pair%%:*} differs from the host's: $(cmp "$actual" "$expected" 2>&1 | head -1)"
        match=false
    fi
done

# Sizes of the linked production image: flash holds what is loaded there (vector table,
# code, read-only data, and the initial values of .data); RAM holds .data, .bss and the stack.
section() {
    local hex
    hex="$(readelf -S --wide "${2:-$elf}" | sed -n 's/^ *\[ *[0-9]*\] *//p' |
        awk -v name="$1" '$1 == name {print $5}' | head -1)"
    echo $((16#${hex:-0}))
}
# Where a section starts in memory.
address() {
    local hex
    hex="$(readelf -S --wide "${2:-$elf}" | sed -n 's/^ *\[ *[0-9]*\] *//p' |
        awk -v name="$1" '$1 == name {print $3}' | head -1)"
    echo $((16#${hex:-0}))
}
check_flash=0
for name in .vector_table .text .rodata .data; do
    check_flash=$((check_flash + $(section "$name" "$check_elf")))
done
vector_table=$(section .vector_table)
text=$(section .text)
rodata=$(section .rodata)
data=$(section .data)
bss=$(section .bss)
uninit=$(section .uninit)
flash=$((vector_table + text + rodata + data))
stack=$(field stack_bytes)
weights=$(stat -c %s weights/policy.wlw)

decided=$(field decisions)
infer=$(field infer_instructions)
decide=$(field decide_instructions)
ticks=$(field ticks)
tick_instructions=$(field tick_instructions)
calibration=$(field calibration_instructions)
calibration_expected=$(field calibration_expected)
boot=$(field instructions_boot_check)
# A decision's count is the policy's (height map and state in, logits out: what the MACs are
# in, the anchors' measure); the decision rule, guard and arrival are counted apart.
per_decision=$((infer / decided))
per_rule=$((decide / decided))
scalar=$(field scalar_infer_instructions)
per_decision_scalar=$((scalar / decided))
kernel_mismatches=$(field kernel_mismatches)
if [ "$kernel_mismatches" != 0 ]; then
    log "error: the DSP kernel's outputs differ from the scalar kernel's on $kernel_mismatches decisions"
    match=false
fi
quantize_mismatches=$(field input_quantization_mismatches)
if [ "$quantize_mismatches" != 0 ]; then
    log "error: the DSP kernel's input quantization differs from the scalar kernel's on $quantize_mismatches of the checked records"
    match=false
fi
per_tick=$((tick_instructions / ticks))

if [ "$calibration" != "$calibration_expected" ]; then
    log "error: the instruction clock counted $calibration for a loop of $calibration_expected"
    match=false
fi
# The production image's own stack: one held-out episode in the loop (the world and the
# motors on the host, src/hil), its free RAM painted by QEMU's loader before the core starts
# and saved by QEMU's monitor at the end. The fault tests and the equivalence with the host's
# closed loop are scripts/hil.sh's.
log "the production image in the loop (held-out complex-0), for its RAM"
hil=true
set +e
"$root/target/release/wheelleg" demo --controller qemu --firmware "$elf" \
    --scenarios eval/heldout-complex-s1000000.json --out "$work/episode" >"$work/episode.txt" 2>&1
episode_status=$?
set -e
cat "$work/episode.txt" >&2
production_ram="$(grep -o 'RAM: *[0-9]* bytes' "$work/episode.txt" | grep -o '[0-9]*' | head -1)"
production_stack="$(grep -o 'stack at its deepest [0-9]*' "$work/episode.txt" | grep -o '[0-9]*' | head -1)"
if [ "$episode_status" -ne 0 ] || ! grep -q "^result: *SUCCESS" "$work/episode.txt" ||
    [ -z "$production_ram" ] || [ -z "$production_stack" ]; then
    log "error: the production image's episode in the loop failed, or reported no RAM"
    hil=false
    production_ram=$(($(address .uninit) + uninit - $(address .data) + stack))
    production_stack=$stack
fi
# The statics' RAM: from .data's start to .uninit's end, the alignment gaps between them included.
statics=$(($(address .uninit) + uninit - $(address .data)))
if [ "$hil" = true ] && [ "$production_ram" -ne $((statics + production_stack)) ]; then
    log "error: the loop's statics ($((production_ram - production_stack)) B) are not the ELF's ($statics B)"
    hil=false
fi
ram=$production_ram

fits=true
if [ "$flash" -gt "$FLASH_BUDGET" ] || [ "$ram" -gt "$RAM_BUDGET" ]; then
    log "error: over budget: flash $flash of $FLASH_BUDGET, RAM $ram of $RAM_BUDGET"
    fits=false
fi

if $json; then
    echo "{\"decisions_match\": $match, \"flash_bytes\": $flash, \"ram_bytes\": $ram, \"stack_bytes\": $production_stack, \"instructions_per_decision\": $per_decision, \"instructions_per_tick\": $per_tick, \"instructions_boot_check\": $boot, \"decisions\": $decided, \"ticks\": $ticks, \"weights_bytes\": $weights, \"text_bytes\": $((vector_table + text)), \"rodata_bytes\": $rodata, \"data_bytes\": $data, \"bss_bytes\": $((bss + uninit)), \"fits_budget\": $fits, \"flash_budget_bytes\": $FLASH_BUDGET, \"ram_budget_bytes\": $RAM_BUDGET, \"instructions_rule_guard_arrival\": $per_rule, \"calibration_instructions\": $calibration, \"instructions_per_decision_scalar\": $per_decision_scalar, \"check_image_flash_bytes\": $check_flash, \"check_image_stack_bytes\": $stack, \"production_episode\": $hil}"
else
    cat <<EOF
decisions match the host's:   $match ($decided decisions, $ticks control periods)
fits the budget:              $fits ($((FLASH_BUDGET / 1024)) KiB flash, $((RAM_BUDGET / 1024)) KiB RAM; production image)
flash:                        $flash bytes (code $((vector_table + text)), read-only data $rodata of which weights $weights, data $data)
RAM:                          $ram bytes (data $data, bss $((bss + uninit)), peak stack $production_stack of the production image in the loop; the check image's $stack)
check image's flash:          $check_flash bytes (with the check harness)
instructions per decision:    $per_decision (policy, DSP kernel; scalar kernel $per_decision_scalar), and $per_rule for the rule, guard and arrival
instructions per period:      $per_tick
instructions for boot check:  $boot
EOF
fi
$match && $fits && $hil
