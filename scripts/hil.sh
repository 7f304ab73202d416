#!/usr/bin/env bash
# The controller firmware in the loop (tests/hil.rs): the production image in QEMU's
# mps2-an386 between the world and the simulated motors, on its observation link (UART 1) and
# its SLCAN adapter link (UART 2):
#   - the first HIL_SCENES held-out complex scenes (default 2) reach the in-process closed
#     loop's outcomes with the same on-board stack, and their bus logs decode with ODrive's DBC;
#   - a silent axis, lost CAN frames, a dead CAN link, a stalled and a corrupt observation link
#     each end in the documented safe stop within the documented timeout;
#   - the firmware's RAM in use (statics and the stack painted by QEMU's loader) fits 128 KiB
#     (the budget's STM32G474-class part), and its busiest control period fits 10 ms at 170 MHz;
#   - on the emulated clock (QEMU's instruction clock, which decisions cost as on a board) the
#     same scenes' outcomes, every period's setpoints within 1 ms of due, no watchdog trip; a
#     500 ms decision abandoned at its deadline while the robot holds; the faults again.
# Installs the embedded toolchain and QEMU if needed (scripts/embedded-toolchain.sh).
#
#   bash scripts/hil.sh
#   HIL_SCENES=50 bash scripts/hil.sh
#   HIL_SKIP=21 HIL_SCENES=2 bash scripts/hil.sh   # held-out scenes 21 and 22
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/embedded-toolchain.sh >&2
# The production image, and the same built for the emulated clock (its own target folder).
(cd controller && nice -n 10 cargo +nightly build --quiet --release --bin wheelleg-controller &&
    nice -n 10 cargo +nightly build --quiet --release --bin wheelleg-controller \
        --features emulated-clock --target-dir target/emulated-clock)
WHEELLEG_HIL_SCENES="${HIL_SCENES:-2}" WHEELLEG_HIL_SKIP="${HIL_SKIP:-0}" nice -n 10 cargo test --quiet --workspace --release --test hil -- \
    --ignored --test-threads=1 --nocapture
