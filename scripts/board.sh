#!/usr/bin/env bash
# The controller firmware for a real part, the NUCLEO-G474RE (board/): builds its image and
# measures it against the part (STM32G474RE: 512 KiB flash, 128 KiB SRAM). Nothing runs it
# here: the logic is checked in QEMU (scripts/mcu.sh, scripts/hil.sh), and the board needs
# the hardware (docs/controller.md, "A real board: NUCLEO-G474RE").
#
#   bash scripts/board.sh      one JSON object on stdout (the build's output on stderr)
#
# Flash is every allocated section linked into the flash region plus .data's initial values;
# RAM is the statics (.data, .bss, .uninit). The stack is not in it: it can only be measured
# on the part (the QEMU image's, painted in the loop, is in scripts/mcu.sh's report), and
# ram_free_for_stack_bytes says what is left for it. Exits non-zero when the build fails, the
# image was not linked for the part's memory (board/memory.x), or it does not fit.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

log() { echo "board: $*" >&2; }

FLASH_ORIGIN=$((0x08000000))
FLASH_BUDGET=$((512 * 1024))
RAM_ORIGIN=$((0x20000000))
RAM_BUDGET=$((128 * 1024))

bash scripts/embedded-toolchain.sh >&2

log "building the NUCLEO-G474RE image (thumbv7em-none-eabihf, release)"
(cd board && nice -n 10 cargo +nightly build --quiet --release) >&2
elf=board/target/thumbv7em-none-eabihf/release/wheelleg-board

# Section headers without their index: name, type, address, offset, size, entry size, flags.
sections="$(readelf -S --wide "$elf" | sed -n 's/^ *\[ *[0-9]*\] *//p')"
field() {
    local hex
    hex="$(awk -v name="$1" -v column="$2" '$1 == name {print $column}' <<<"$sections" | head -1)"
    echo $((16#${hex:-0}))
}
size() { field "$1" 5; }

if [ "$(field .vector_table 3)" -ne "$FLASH_ORIGIN" ]; then
    log "error: the vector table is not at the flash's start: the image was linked with another memory.x than board/memory.x"
    exit 1
fi

flash=0
ram=0
while read -r name _type address _offset bytes _entry flags _rest; do
    # Sections without flags (the table's first, attributes) shift the columns: skip them.
    [[ "$flags" == *A* ]] || continue
    address=$((16#$address))
    bytes=$((16#$bytes))
    if ((address >= FLASH_ORIGIN && address < FLASH_ORIGIN + FLASH_BUDGET)); then
        flash=$((flash + bytes))
    elif ((address >= RAM_ORIGIN && address < RAM_ORIGIN + RAM_BUDGET)); then
        ram=$((ram + bytes))
    elif ((bytes > 0)); then
        log "error: section $name at $(printf '0x%08x' "$address") is outside the part's flash and RAM"
        exit 1
    fi
done <<<"$sections"

data=$(size .data)
# .data's initial values are stored in flash and copied to RAM at start-up.
flash=$((flash + data))
text=$(($(size .vector_table) + $(size .text)))
rodata=$(size .rodata)
bss=$(($(size .bss) + $(size .uninit)))
weights=$(stat -c %s "${WHEELLEG_WEIGHTS:-weights/policy.wlw}")

fits=true
if [ "$flash" -gt "$FLASH_BUDGET" ] || [ "$ram" -gt "$RAM_BUDGET" ]; then
    log "error: over budget: flash $flash of $FLASH_BUDGET, RAM $ram of $RAM_BUDGET"
    fits=false
fi

echo "{\"flash_bytes\": $flash, \"ram_bytes\": $ram, \"flash_budget_bytes\": $FLASH_BUDGET, \"ram_budget_bytes\": $RAM_BUDGET, \"fits_budget\": $fits, \"text_bytes\": $text, \"rodata_bytes\": $rodata, \"data_bytes\": $data, \"bss_bytes\": $bss, \"weights_bytes\": $weights, \"ram_free_for_stack_bytes\": $((RAM_BUDGET - ram))}"
$fits
