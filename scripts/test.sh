#!/usr/bin/env bash
# The project's tests: every crate's unit and integration tests (release mode: the simulator and
# the learning tests are too slow in debug), the no_std proof, and the CAN wire check against
# ODrive's own DBC.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# Property tests draw from a fixed seed, so that a run is reproducible and CI cannot flake; set
# PROPTEST_RNG_SEED to explore other cases (failures are saved next to the test and replayed).
export PROPTEST_RNG_SEED="${PROPTEST_RNG_SEED:-20261124}"
# The SLCAN demo runs controller and motors in real time against a 2 mm tracking tolerance; the
# other closed-loop tests beside it on a 2-core machine starve it past that, so it runs alone.
realtime=demo_binary_runs_the_loop_through_an_slcan_adapter
# Every cargo command here builds the whole workspace's feature set (`--workspace`, with the
# examples, which bring the dev-dependencies' features): a single package's own set (`-p`) differs
# in features of shared crates (libc, either) and rebuilds burn and everything above it.
cargo test --workspace --release -- --skip "$realtime"
cargo test --workspace --release --test closed_loop "$realtime"
cargo build --quiet --workspace --release --bins --examples

bash runtime/nostd-check/check.sh

log="$(mktemp -d)/bus.log"
target/release/examples/closed_loop_log "$log"
python3 tools/check_dbc.py "$log"

# A second robot's bus: the demo on robots/strider.toml (nodes 21 to 36) writes a log that
# decodes with the DBC written for that robot.
strider="$(mktemp -d)"
target/release/wheelleg generate --robot robots/strider.toml --kind straight --count 1 \
    --seed 3 --out "$strider/scene.json" >/dev/null
target/release/wheelleg demo --robot robots/strider.toml --planner \
    --scenarios "$strider/scene.json" --out "$strider/demo" >/dev/null
python3 tools/gen_dbc.py --robot robots/strider.toml >"$strider/strider.dbc"
python3 tools/check_dbc.py "$strider/demo/bus.log" --project-dbc "$strider/strider.dbc"

# SLCAN: python-can's slcan interface drives a simulated wheel axis through firmware_sim's TCP
# endpoint. python-can and pyserial are pinned in tools/requirements-slcan.txt and installed in
# a virtual environment under target/, so the system Python is left alone.
venv="target/slcan-venv"
if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tools/requirements-slcan.txt
"$venv/bin/python" tools/slcan_python_can.py --firmware-sim target/release/firmware_sim
