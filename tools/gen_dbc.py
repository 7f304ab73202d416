#!/usr/bin/env python3
"""Generate a robot's DBC: ODrive CANSimple messages for every node of its node map.

The node map is the robot description's [can.axes] (robots/NAME.toml; the shipped robot's is
runtime/src/can/node_map.rs's nominal map, nodes 1 to 16 in Axis::ALL order); payload layouts
are ODrive's (third_party/odrive/odrive-cansimple.dbc), with the same signal names so
tools/check_dbc.py can compare the two decodings.

    python3 tools/gen_dbc.py > docs/wheelleg.dbc                        # the shipped robot
    python3 tools/gen_dbc.py --robot robots/NAME.toml > NAME.dbc        # another robot
"""

import argparse
import os
import sys
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LEGS = ["FL", "FR", "RL", "RR"]
# The description's key of each axis, in the order of AXES.
LEG_KEYS = ["front_left", "front_right", "rear_left", "rear_right"]
JOINT_KEYS = ["hip", "knee", "wheel_mount"]
AXIS_KEYS = [f"{leg}_{j}" for leg in LEG_KEYS for j in JOINT_KEYS] + [f"{leg}_wheel" for leg in LEG_KEYS]
JOINTS = ["Hip", "Knee", "WheelMount"]
AXES = [f"{leg}_{j}" for leg in LEGS for j in JOINTS] + [f"{leg}_Wheel" for leg in LEGS]
HOST = "Host"

# (cmd, name, dlc, sender is axis?, [(signal, start, size, signed, scale, unit, is_float)])
COMMON = [
    (0x01, "Heartbeat", 8, True, [("Axis_Error", 0, 32, False, 1, "", False),
                                  ("Axis_State", 32, 32, False, 1, "", False)]),
    (0x02, "Estop", 0, False, []),
    (0x07, "Set_Axis_State", 8, False, [("Axis_Requested_State", 0, 32, False, 1, "", False)]),
    (0x09, "Get_Encoder_Estimates", 8, True, [("Pos_Estimate", 0, 32, False, 1, "turns", True),
                                              ("Vel_Estimate", 32, 32, False, 1, "turns/s", True)]),
    (0x0B, "Set_Controller_Mode", 8, False, [("Control_Mode", 0, 32, False, 1, "", False),
                                             ("Input_Mode", 32, 32, False, 1, "", False)]),
    (0x18, "Clear_Errors", 0, False, []),
]
POS = (0x0C, "Set_Input_Pos", 8, False, [("Input_Pos", 0, 32, False, 1, "turns", True),
                                         ("Vel_FF", 32, 16, True, 0.001, "turns/s", False),
                                         ("Torque_FF", 48, 16, True, 0.001, "Nm", False)])
VEL = (0x0D, "Set_Input_Vel", 8, False, [("Input_Vel", 0, 32, False, 1, "turns/s", True),
                                         ("Input_Torque_FF", 32, 32, False, 1, "Nm", True)])

STATES = {0: "UNDEFINED", 1: "IDLE", 2: "STARTUP_SEQUENCE", 3: "FULL_CALIBRATION_SEQUENCE",
          4: "MOTOR_CALIBRATION", 6: "ENCODER_INDEX_SEARCH", 7: "ENCODER_OFFSET_CALIBRATION",
          8: "CLOSED_LOOP_CONTROL", 9: "LOCKIN_SPIN", 10: "ENCODER_DIR_FIND", 11: "HOMING",
          12: "ENCODER_HALL_POLARITY_CALIBRATION", 13: "ENCODER_HALL_PHASE_CALIBRATION"}


def node_ids(path):
    """Each axis's node id from a robot description, in the order of AXES."""
    with open(path, "rb") as f:
        axes = tomllib.load(f)["can"]["axes"]
    return [axes[key]["node_id"] for key in AXIS_KEYS]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default=os.path.join(ROOT, "robots", "wheelleg.toml"),
                        help="robot description (default: the shipped robot)")
    args = parser.parse_args()
    try:
        nodes = node_ids(args.robot)
    except (OSError, KeyError, tomllib.TOMLDecodeError) as e:
        sys.exit(f"gen_dbc: cannot read the node map of {args.robot}: {e!r}")
    out = ['VERSION "wheelleg 1"', "", "", "NS_ :", "", "BS_:", "",
           "BU_: " + " ".join([HOST] + AXES), "", ""]
    floats, values, comments = [], [], []
    for index, axis in enumerate(AXES):
        node = nodes[index]
        messages = COMMON + [VEL if axis.endswith("_Wheel") else POS]
        for cmd, name, dlc, from_axis, signals in sorted(messages):
            frame_id = node << 5 | cmd
            sender, receiver = (axis, HOST) if from_axis else (HOST, axis)
            out.append(f"BO_ {frame_id} {axis}_{name}: {dlc} {sender}")
            for sig, start, size, signed, scale, unit, is_float in signals:
                sign = "-" if signed else "+"
                out.append(f' SG_ {sig} : {start}|{size}@1{sign} ({scale:g},0) [0|0] "{unit}" {receiver}')
                if is_float:
                    floats.append(f"SIG_VALTYPE_ {frame_id} {sig} : 1;")
                if sig in ("Axis_State", "Axis_Requested_State"):
                    table = " ".join(f'{k} "{v}"' for k, v in STATES.items())
                    values.append(f"VAL_ {frame_id} {sig} {table} ;")
            out.append("")
        comments.append(f'CM_ BU_ {axis} "ODrive node {node}";')
    out += comments + [""] + values + [""] + floats + [""]
    print("\n".join(out))


if __name__ == "__main__":
    main()
