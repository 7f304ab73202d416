#!/usr/bin/env python3
"""Decode a `candump -L` log with ODrive's CANSimple DBC and check every frame.

Usage:
    python3 tools/check_dbc.py LOG [--dbc third_party/odrive/odrive-cansimple.dbc] [--project-dbc docs/wheelleg.dbc]

Installs cantools from PyPI (tools/requirements.txt) if it is missing.

ODrive's DBC lists every message at node 0, so a frame's id is masked to its low 5 bits (the
command) before lookup; the high 6 bits are the node id. Estop (0x02) and Clear_Errors (0x18)
are not in ODrive's DBC: they carry no payload and are checked for an empty payload instead.
Nor is Get_Version (0x00, ODrive 0.6's, eight single-byte fields): its answers are checked for
their length.
With --project-dbc, every frame is also decoded with the project's own DBC (full ids, one message
per node), and the two decodings must agree.

Exits non-zero if any frame fails to decode, if a decoded value is out of range for its message
(non-finite float, unknown axis state), or if the two DBCs disagree.
"""

import argparse
import math
import os
import subprocess
import sys
from collections import Counter

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DEFAULT_DBC = os.path.join(ROOT, "third_party", "odrive", "odrive-cansimple.dbc")
DEFAULT_PROJECT_DBC = os.path.join(ROOT, "docs", "wheelleg.dbc")

EMPTY_COMMANDS = {0x02: "Estop", 0x18: "Clear_Errors"}
AXIS_STATES = {0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11, 12, 13}


def ensure_cantools():
    try:
        import cantools  # noqa: F401
    except ImportError:
        req = os.path.join(HERE, "requirements.txt")
        print(f"installing cantools ({req})", file=sys.stderr)
        subprocess.check_call([sys.executable, "-m", "pip", "install", "-q", "-r", req])
    import cantools

    return cantools


def parse_line(line):
    """(timestamp, interface, id, remote, data) from `(t) iface ID#DATA`."""
    ts, iface, frame = line.split()
    ident, payload = frame.split("#", 1)
    if len(ident) != 3:
        raise ValueError(f"not a standard id: {ident}")
    remote = payload.startswith("R")
    data = b"" if remote else bytes.fromhex(payload)
    return float(ts.strip("()")), iface, int(ident, 16), remote, data


def check_values(name, values):
    for key, value in values.items():
        if isinstance(value, float) and not math.isfinite(value):
            return f"{name}.{key} is not finite"
    if name == "Heartbeat" and values.get("Axis_State") not in AXIS_STATES:
        return f"Heartbeat.Axis_State {values.get('Axis_State')} is not an ODrive state"
    if name == "Set_Axis_State" and values.get("Axis_Requested_State") not in AXIS_STATES:
        return f"Set_Axis_State {values.get('Axis_Requested_State')} is not an ODrive state"
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--dbc", default=DEFAULT_DBC)
    ap.add_argument("--project-dbc", default=DEFAULT_PROJECT_DBC)
    args = ap.parse_args()

    cantools = ensure_cantools()
    odrive = cantools.database.load_file(args.dbc)
    project = None
    if args.project_dbc and os.path.exists(args.project_dbc):
        project = cantools.database.load_file(args.project_dbc)

    counts = Counter()
    nodes = Counter()
    errors = []
    with open(args.log) as f:
        for lineno, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                _, _, ident, remote, data = parse_line(line)
            except ValueError as e:
                errors.append(f"line {lineno}: unparsable: {e}")
                continue
            node, cmd = ident >> 5, ident & 0x1F
            nodes[node] += 1
            if remote:
                counts["(remote request)"] += 1
                continue
            if cmd == 0x00:
                if len(data) != 8:
                    errors.append(f"line {lineno}: Get_Version with {len(data)} bytes, not 8")
                counts["Get_Version"] += 1
                continue
            if cmd in EMPTY_COMMANDS:
                if data:
                    errors.append(f"line {lineno}: {EMPTY_COMMANDS[cmd]} with payload {data.hex()}")
                counts[EMPTY_COMMANDS[cmd]] += 1
                continue
            try:
                msg = odrive.get_message_by_frame_id(cmd)
                values = msg.decode(data, decode_choices=False)
            except Exception as e:  # cantools raises several types
                errors.append(f"line {lineno}: {line.strip()}: {e}")
                continue
            problem = check_values(msg.name, values)
            if problem:
                errors.append(f"line {lineno}: {problem}")
            if project is not None:
                try:
                    ours = project.get_message_by_frame_id(ident)
                    mine = ours.decode(data, decode_choices=False)
                except Exception as e:
                    errors.append(f"line {lineno}: project DBC: {e}")
                else:
                    # Signals are named alike in both DBCs; compare values bit for bit.
                    for key, value in values.items():
                        if key in mine and mine[key] != value and not (
                            isinstance(value, float) and math.isnan(value)
                        ):
                            errors.append(
                                f"line {lineno}: {msg.name}.{key}: ODrive DBC {value} != project DBC {mine[key]}"
                            )
            counts[msg.name] += 1

    total = sum(counts.values())
    print(f"{args.log}: {total} frames from nodes {sorted(nodes)}")
    for name, n in sorted(counts.items()):
        print(f"  {name:24s} {n}")
    if errors:
        for e in errors[:20]:
            print("ERROR", e, file=sys.stderr)
        print(f"{len(errors)} frame(s) failed", file=sys.stderr)
        return 1
    if total == 0:
        print("ERROR: empty log", file=sys.stderr)
        return 1
    print(f"all {total} frames decode with {os.path.basename(args.dbc)}"
          + (f" and {os.path.basename(args.project_dbc)}" if project else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
