#!/usr/bin/env python3
"""Generate docs/wheelleg.dbc: ODrive CANSimple messages for every node of the robot's node map.

The node map is runtime/src/can/node_map.rs (node 1 + index in Axis::ALL); payload layouts are
ODrive's (third_party/odrive/odrive-cansimple.dbc), with the same signal names so tools/check_dbc.py can
compare the two decodings. Run: python3 tools/gen_dbc.py > docs/wheelleg.dbc
"""

LEGS = ["FL", "FR", "RL", "RR"]
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


def main():
    out = ['VERSION "wheelleg 1"', "", "", "NS_ :", "", "BS_:", "",
           "BU_: " + " ".join([HOST] + AXES), "", ""]
    floats, values, comments = [], [], []
    for index, axis in enumerate(AXES):
        node = index + 1
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
