#!/usr/bin/env python3
"""Drive the simulated axes through their SLCAN endpoint with python-can's `slcan` interface.

Usage:
    python3 tools/slcan_python_can.py [--firmware-sim target/release/firmware_sim] [--node 13]

Starts `firmware_sim --slcan tcp:127.0.0.1:0` (the port it binds is read from its first line on
stdout), connects with `can.Bus(interface="slcan", channel="socket://127.0.0.1:PORT",
bitrate=1000000)` and checks, against the CANSimple protocol of docs/can-protocol.md:

1. the adapter answers V and N;
2. a heartbeat arrives from every one of the 16 axes (nodes 1-16);
3. a wheel axis (node 13 by default) set to velocity control (Set_Controller_Mode) and closed
   loop (Set_Axis_State) reports closed loop in its heartbeat;
4. under Set_Input_Vel (sent every 20 ms, inside the axes' 100 ms watchdog) its
   Get_Encoder_Estimates velocity rises to the command and its position advances;
5. after Estop its heartbeat reports idle with ESTOP_REQUESTED latched and its velocity decays
   to zero.

Exits non-zero, naming the step, if any of that does not happen (or python-can is missing: the
test script installs it from tools/requirements-slcan.txt into a virtual environment).
"""

import argparse
import os
import struct
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

HEARTBEAT = 0x01
ESTOP = 0x02
SET_AXIS_STATE = 0x07
ENCODER_ESTIMATES = 0x09
SET_CONTROLLER_MODE = 0x0B
SET_INPUT_VEL = 0x0D
CLOSED_LOOP = 8
IDLE = 1
VELOCITY_CONTROL = 2
PASSTHROUGH = 1
ESTOP_REQUESTED = 0x4000
NODES = range(1, 17)


class Failure(Exception):
    pass


def start_firmware_sim(binary, duration_s):
    proc = subprocess.Popen(
        [binary, "--slcan", "tcp:127.0.0.1:0", "--duration-s", str(duration_s)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    result = {}

    def read_first_line():
        result["line"] = proc.stdout.readline()

    reader = threading.Thread(target=read_first_line, daemon=True)
    reader.start()
    reader.join(timeout=20)
    line = result.get("line", "")
    marker = "SLCAN on tcp:"
    if marker not in line:
        proc.kill()
        _, err = proc.communicate()
        raise Failure(f"firmware_sim did not report its SLCAN address (stdout {line!r}, stderr {err!r})")
    return proc, line.split(marker, 1)[1].strip()


def split_id(msg):
    return msg.arbitration_id >> 5, msg.arbitration_id & 0x1F


def send(bus, can, node, cmd, data=b""):
    bus.send(can.Message(arbitration_id=node << 5 | cmd, is_extended_id=False, data=data))


def run(args):
    import can

    proc, address = start_firmware_sim(args.firmware_sim, args.duration_s)
    print(f"firmware_sim serves SLCAN on tcp:{address}")
    bus = None
    try:
        bus = can.Bus(
            interface="slcan",
            channel=f"socket://{address}",
            bitrate=1_000_000,
            sleep_after_open=0,
        )
        version = bus.get_version(timeout=2)
        serial_number = bus.get_serial_number(timeout=2)
        if version == (None, None) or not serial_number:
            raise Failure(f"no answer to V / N (version {version}, serial number {serial_number!r})")
        print(f"adapter version {version}, serial number {serial_number}")

        # 2. Heartbeats from every axis (they come every 100 ms).
        seen = {}
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and len(seen) < len(NODES):
            msg = bus.recv(timeout=0.1)
            if msg is not None and not msg.is_remote_frame:
                node, cmd = split_id(msg)
                if cmd == HEARTBEAT and node in NODES:
                    seen[node] = struct.unpack_from("<IB", bytes(msg.data))
        missing = [n for n in NODES if n not in seen]
        if missing:
            raise Failure(f"no heartbeat within 3 s from nodes {missing}")
        print(f"heartbeats from all {len(seen)} axes: state {sorted({s for _, s in seen.values()})}")

        # 3. + 4. Velocity control, closed loop, a velocity setpoint kept alive every 20 ms.
        node, target = args.node, args.vel_turns_per_s
        send(bus, can, node, SET_CONTROLLER_MODE, struct.pack("<II", VELOCITY_CONTROL, PASSTHROUGH))
        send(bus, can, node, SET_AXIS_STATE, struct.pack("<II", CLOSED_LOOP, 0))
        states, estimates = [], []
        next_setpoint = 0.0
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            now = time.monotonic()
            if now >= next_setpoint:
                send(bus, can, node, SET_INPUT_VEL, struct.pack("<ff", target, 0.0))
                next_setpoint = now + 0.02
            msg = bus.recv(timeout=0.005)
            if msg is None or msg.is_remote_frame or split_id(msg)[0] != node:
                continue
            cmd = split_id(msg)[1]
            if cmd == HEARTBEAT:
                states.append(struct.unpack_from("<IB", bytes(msg.data)))
            elif cmd == ENCODER_ESTIMATES:
                estimates.append(struct.unpack("<ff", bytes(msg.data)))
        if (0, CLOSED_LOOP) not in states:
            raise Failure(f"node {node} never reported closed loop without errors: heartbeats {states}")
        if len(estimates) < 20:
            raise Failure(f"only {len(estimates)} encoder estimates from node {node} in 1.5 s")
        first_vel, last_vel = estimates[0][1], estimates[-1][1]
        if abs(last_vel - target) > 0.05 * abs(target) or abs(first_vel - target) <= abs(last_vel - target):
            raise Failure(
                f"node {node} velocity did not approach {target} turns/s: {first_vel:.3f} -> {last_vel:.3f}"
            )
        if estimates[-1][0] - estimates[0][0] < 0.5 * target:
            raise Failure(f"node {node} position did not advance: {estimates[0][0]:.3f} -> {estimates[-1][0]:.3f}")
        print(
            f"node {node} closed loop: velocity {first_vel:.3f} -> {last_vel:.3f} turns/s "
            f"(command {target}), position {estimates[0][0]:.3f} -> {estimates[-1][0]:.3f} turns, "
            f"{len(estimates)} estimates"
        )

        # 5. Estop: idle, ESTOP_REQUESTED latched, the wheel spins down.
        send(bus, can, node, ESTOP)
        states, estimates = [], []
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            msg = bus.recv(timeout=0.01)
            if msg is None or msg.is_remote_frame or split_id(msg)[0] != node:
                continue
            cmd = split_id(msg)[1]
            if cmd == HEARTBEAT:
                states.append(struct.unpack_from("<IB", bytes(msg.data)))
            elif cmd == ENCODER_ESTIMATES:
                estimates.append(struct.unpack("<ff", bytes(msg.data)))
        if not states or states[-1][1] != IDLE or not states[-1][0] & ESTOP_REQUESTED:
            raise Failure(f"node {node} after Estop is not idle with ESTOP_REQUESTED: heartbeats {states}")
        if not estimates or abs(estimates[-1][1]) > 0.01:
            last = estimates[-1][1] if estimates else None
            raise Failure(f"node {node} after Estop still turns: velocity {last}")
        print(
            f"node {node} after Estop: state {states[-1][1]} (idle), error {states[-1][0]:#x}, "
            f"velocity {estimates[-1][1]:.4f} turns/s"
        )
    finally:
        if bus is not None:
            bus.shutdown()
        if proc.poll() is not None:
            _, err = proc.communicate()
            raise Failure(f"firmware_sim exited early ({proc.returncode}): {err}")
        proc.terminate()
        try:
            proc.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--firmware-sim", default=os.path.join(ROOT, "target", "release", "firmware_sim"))
    parser.add_argument("--node", type=int, default=13, help="a wheel axis (13-16)")
    parser.add_argument("--vel-turns-per-s", type=float, default=4.0)
    parser.add_argument("--duration-s", type=float, default=120.0, help="firmware_sim's own time limit")
    args = parser.parse_args()
    try:
        import can  # noqa: F401
        import serial  # noqa: F401
    except ImportError as e:
        print(f"slcan_python_can: {e}; pip install -r {os.path.join(HERE, 'requirements-slcan.txt')}", file=sys.stderr)
        return 2
    try:
        run(args)
    except Failure as e:
        print(f"slcan_python_can: FAILED: {e}", file=sys.stderr)
        return 1
    print("slcan_python_can: python-can drove a simulated wheel axis over SLCAN: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
