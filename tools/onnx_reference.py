#!/usr/bin/env python3
"""onnxruntime reference for the int8 policy runtime: same network, batch 1, one thread.

Reads an exported `.wlw` weights file with its own parser (written from docs/weights-format.md
alone, so it also checks that the page is enough to write a reader), rebuilds the float network
as an ONNX graph (Conv/Relu x3, Flatten, Concat with the state, Gemm/Relu, two Gemm heads) with
the dequantized weights, quantizes that graph with onnxruntime's own static int8 quantization
(calibrated on generated observations) and prints the latency per decision of:

- onnxruntime, float graph;
- onnxruntime, int8 graph (QDQ format, and QOperator format: QLinearConv / QGemm);
- the per-call overhead of `InferenceSession.run` from Python (a graph with one Identity node),
  which is included in the figures above and subtracted in the "net" column.

It also checks the graph against the file: logits of the float graph vs an integer reference of
the `.wlw` semantics written here in numpy (same page), and greedy-action agreement.

With `--runtime-cpu N`, measures the Rust runtime's CPU time per decision in the same run (the
`decisions` example: N decisions minus 0, user time), and with `--cargo-bench` runs
`cargo bench -p wheelleg-runtime --bench inference` right after (wall clock); both print the
ratios of onnxruntime's figures to the runtime's. On a shared machine compare CPU times: wall
clock includes waiting for a core.

Usage (installs its own packages into a virtualenv, by default under .venv-onnx/):
    python3 tools/onnx_reference.py [--weights weights/policy.wlw] [--seconds 2]
                                    [--runtime-cpu 100000] [--cargo-bench] [--json]
"""
import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def ensure_venv(venv_dir):
    """Re-executes this script inside a virtualenv that has tools/requirements-onnx.txt."""
    if os.environ.get("WHEELLEG_ONNX_VENV") == "1":
        return
    python = os.path.join(venv_dir, "bin", "python")
    stamp = os.path.join(venv_dir, ".requirements-onnx.txt")
    requirements = os.path.join(HERE, "requirements-onnx.txt")
    with open(requirements) as f:
        wanted = f.read()
    have = open(stamp).read() if os.path.exists(stamp) else None
    if not os.path.exists(python) or have != wanted:
        print(f"installing {requirements} into {venv_dir}", file=sys.stderr)
        subprocess.check_call([sys.executable, "-m", "venv", venv_dir])
        subprocess.check_call([python, "-m", "pip", "install", "-q", "-r", requirements])
        with open(stamp, "w") as f:
            f.write(wanted)
    env = dict(os.environ, WHEELLEG_ONNX_VENV="1")
    os.execve(python, [python, os.path.abspath(__file__)] + sys.argv[1:], env)


# ---------------------------------------------------------------------------------------------
# .wlw reader (docs/weights-format.md)


class Reader:
    def __init__(self, data):
        self.data = data
        self.pos = 0

    def take(self, n):
        if self.pos + n > len(self.data):
            raise ValueError("truncated")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def varint(self, max_bytes):
        value, shift = 0, 0
        for _ in range(max_bytes):
            byte = self.take(1)[0]
            value |= (byte & 0x7F) << shift
            shift += 7
            if byte & 0x80 == 0:
                return value
        raise ValueError("varint too long")

    def u8(self):
        return self.take(1)[0]

    def i8(self):
        return struct.unpack("<b", self.take(1))[0]

    def u16(self):
        return self.varint(3)

    def i32(self):
        z = self.varint(5)
        return (z >> 1) ^ -(z & 1)

    def f32(self):
        return struct.unpack("<f", self.take(4))[0]

    def boolean(self):
        b = self.u8()
        if b > 1:
            raise ValueError("bad bool")
        return b == 1

    def bytes(self):
        return self.take(self.varint(5))

    def input_quant(self):
        return dict(scale_m=self.f32(), zero_point=self.i8(), multiplier=self.i32(), shift=self.i8())

    def act_quant(self):
        return dict(scale=self.f32(), zero_point=self.i8())

    def tensors(self, record):
        record["weights"] = self.bytes()
        record["bias"] = self.bytes()
        record["multipliers"] = self.bytes()
        record["shifts"] = self.bytes()
        return record

    def conv(self):
        r = dict(in_channels=self.u16(), out_channels=self.u16(), kernel=self.u8(),
                 stride=self.u8(), padding=self.u8(), relu=self.boolean(), output=self.act_quant())
        return self.tensors(r)

    def dense(self):
        r = dict(in_features=self.u16(), out_features=self.u16(), relu=self.boolean(),
                 output=self.act_quant())
        return self.tensors(r)


def parse_wlw(data):
    """The model of a .wlw file as dicts of python values and byte strings."""
    if data[:4] != b"WLWM":
        raise ValueError("bad magic")
    r = Reader(data)
    r.take(4)
    version = r.u16()
    # Version 2 has version 1's bytes; the action head's output (int16 logits, zero point 0,
    # no ReLU) and the state features (int16, the int8 grid 256 times finer) differ, see
    # docs/weights-format.md.
    if version not in (1, 2):
        raise ValueError(f"unsupported version {version}")
    payload = r.bytes()
    crc = struct.unpack("<I", r.take(4))[0]
    if r.pos != len(data):
        raise ValueError("trailing bytes")
    if zlib.crc32(data[:-4]) & 0xFFFFFFFF != crc:
        raise ValueError("bad checksum")
    p = Reader(payload)
    model = dict(version=version, input=dict(rows=p.u16(), cols=p.u16(), height=p.input_quant()))
    model["state"] = [p.input_quant() for _ in range(p.varint(5))]
    model["convs"] = [p.conv() for _ in range(p.varint(5))]
    model["hidden"] = [p.dense() for _ in range(p.varint(5))]
    model["action_head"] = p.dense()
    model["value_head"] = p.dense() if p.boolean() else None
    if p.pos != len(payload):
        raise ValueError("bytes after the value head")
    head = model["action_head"]
    if version >= 2 and (head["output"]["zero_point"] != 0 or head["relu"]):
        raise ValueError("version 2 action head must have zero point 0 and no ReLU")
    return model


# ---------------------------------------------------------------------------------------------
# Dequantization and the ONNX graph


def layer_arrays(np, record, rows):
    weights = np.frombuffer(record["weights"], dtype=np.int8).astype(np.int64)
    bias = np.frombuffer(record["bias"], dtype="<i4").astype(np.int64)
    multipliers = np.frombuffer(record["multipliers"], dtype="<i4").astype(np.int64)
    shifts = np.frombuffer(record["shifts"], dtype=np.int8).astype(np.int64)
    assert bias.size == rows and multipliers.size == rows and shifts.size == rows
    return weights.reshape(rows, -1), bias, multipliers, shifts


def state_grid(model, quant):
    """A state feature's int8 grid (metres per int8 step, zero point): the weight folding's
    grid in both versions; a version 2 file stores the int16 step, 256 times smaller."""
    fraction = 256 if model["version"] >= 2 else 1
    return quant["scale_m"] * fraction, quant["zero_point"]


def real_multiplier(np, multipliers, shifts):
    return multipliers.astype(np.float64) * np.power(2.0, shifts.astype(np.float64) - 31.0)


def dequantize(np, model):
    """Float weights and biases per layer: s_w = m * s_out / s_in, W = w * s_w, b = bias * s_in * s_w,
    and the first dense layer's state columns unfolded back to metres (see "Flatten and state")."""
    layers = []
    s_in = model["input"]["height"]["scale_m"]
    channels = 1
    side = (model["input"]["rows"], model["input"]["cols"])
    for conv in model["convs"]:
        o, k = conv["out_channels"], conv["kernel"]
        w, bias, m, s = layer_arrays(np, conv, o)
        s_w = real_multiplier(np, m, s) * conv["output"]["scale"] / s_in
        wf = (w * s_w[:, None]).reshape(o, k, k, channels).transpose(0, 3, 1, 2)  # OHWI -> OIHW
        layers.append(("conv", conv, wf.astype(np.float32), (bias * s_in * s_w).astype(np.float32)))
        s_in = conv["output"]["scale"]
        channels = o
        side = tuple((n + 2 * conv["padding"] - k) // conv["stride"] + 1 for n in side)
    features = channels * side[0] * side[1]
    s_x, zp_x = s_in, (model["convs"][-1]["output"]["zero_point"] if model["convs"]
                       else model["input"]["height"]["zero_point"])
    dense_records = list(model["hidden"])
    heads = [model["action_head"]] + ([model["value_head"]] if model["value_head"] else [])
    first = True
    for record in dense_records + heads:
        o = record["out_features"]
        w, bias, m, s = layer_arrays(np, record, o)
        s_w = real_multiplier(np, m, s) * record["output"]["scale"] / s_in
        wf = w * s_w[:, None]
        bf = bias * s_in * s_w
        if first:
            for j, quant in enumerate(model["state"]):
                t_j, zp_j = state_grid(model, quant)
                column = wf[:, features + j] * s_x / t_j
                bf = bf - column * t_j * (zp_x - zp_j)
                wf[:, features + j] = column
        kind = "dense" if record in dense_records else "head"
        layers.append((kind, record, wf.astype(np.float32), bf.astype(np.float32)))
        if kind == "dense":
            s_in = record["output"]["scale"]
            first = False
    return layers


def build_onnx(np, model, layers, path):
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rows, cols = model["input"]["rows"], model["input"]["cols"]
    n_state = len(model["state"])
    nodes, inits = [], []
    x = "height"
    for i, (kind, record, wf, bf) in enumerate(layers):
        if kind != "conv":
            continue
        inits += [numpy_helper.from_array(wf, f"conv{i}_w"), numpy_helper.from_array(bf, f"conv{i}_b")]
        p, k, st = record["padding"], record["kernel"], record["stride"]
        nodes.append(helper.make_node("Conv", [x, f"conv{i}_w", f"conv{i}_b"], [f"conv{i}"],
                                      kernel_shape=[k, k], strides=[st, st], pads=[p, p, p, p]))
        x = f"conv{i}"
        if record["relu"]:
            nodes.append(helper.make_node("Relu", [x], [f"{x}_relu"]))
            x = f"{x}_relu"
    nodes.append(helper.make_node("Flatten", [x], ["flat"], axis=1))
    nodes.append(helper.make_node("Concat", ["flat", "state"], ["features"], axis=1))
    x = "features"
    hidden_out = x
    outputs = []
    for i, (kind, record, wf, bf) in enumerate(layers):
        if kind == "conv":
            continue
        name = f"dense{i}"
        inits += [numpy_helper.from_array(wf, f"{name}_w"), numpy_helper.from_array(bf, f"{name}_b")]
        src = x if kind == "dense" else hidden_out
        out = name if kind == "dense" else ("logits" if not outputs else "value")
        nodes.append(helper.make_node("Gemm", [src, f"{name}_w", f"{name}_b"], [out], transB=1))
        if kind == "dense":
            x = out
            if record["relu"]:
                nodes.append(helper.make_node("Relu", [x], [f"{x}_relu"]))
                x = f"{x}_relu"
            hidden_out = x
        else:
            outputs.append((out, record["out_features"]))
    graph = helper.make_graph(
        nodes, "wheelleg_policy",
        [helper.make_tensor_value_info("height", TensorProto.FLOAT, [1, 1, rows, cols]),
         helper.make_tensor_value_info("state", TensorProto.FLOAT, [1, n_state])],
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, f]) for n, f in outputs],
        inits)
    onnx_model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx_model.ir_version = 8
    onnx.checker.check_model(onnx_model)
    onnx.save(onnx_model, path)


def identity_graph(path):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])], "overhead",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)


# ---------------------------------------------------------------------------------------------
# Integer reference of the file's semantics (docs/weights-format.md, "Semantics")


def rescale(np, v, m, s):
    right = 31 - s
    return (v.astype(np.int64) * m + (np.int64(1) << (right - 1))) >> right


def int8_forward(np, model, height_mm, state_mm):
    def requant(acc, rec, rows):
        _, bias, m, s = layer_arrays(np, rec, rows)
        zp = rec["output"]["zero_point"]
        low = zp if rec["relu"] else -128
        return np.clip(zp + rescale(np, acc + bias, m, s), low, 127)

    h = model["input"]["height"]
    x = np.clip(h["zero_point"] + rescale(np, height_mm.astype(np.int64), h["multiplier"], h["shift"]),
                -128, 127).reshape(model["input"]["rows"], model["input"]["cols"], 1)
    zp = h["zero_point"]
    for conv in model["convs"]:
        k, st, p, o = conv["kernel"], conv["stride"], conv["padding"], conv["out_channels"]
        w, _, _, _ = layer_arrays(np, conv, o)
        padded = np.pad(x - zp, ((p, p), (p, p), (0, 0)))
        oh = (x.shape[0] + 2 * p - k) // st + 1
        ow = (x.shape[1] + 2 * p - k) // st + 1
        patches = np.stack([padded[oy * st:oy * st + k, ox * st:ox * st + k, :].reshape(-1)
                            for oy in range(oh) for ox in range(ow)])
        x = requant(patches @ w.T, conv, o).reshape(oh, ow, o)
        zp = conv["output"]["zero_point"]
    features = x.transpose(2, 0, 1).reshape(-1)
    if model["version"] >= 2:
        # int16 state, kept apart: the first layer adds its columns' sum divided by 256.
        state = np.array([np.clip(256 * q["zero_point"] + rescale(np, np.int64(v), q["multiplier"],
                                                                  q["shift"]), -32768, 32767)
                          for q, v in zip(model["state"], state_mm)], dtype=np.int64)
        x = features
    else:
        state = np.zeros(0, dtype=np.int64)
        state_q = [np.clip(q["zero_point"] + rescale(np, np.int64(v), q["multiplier"], q["shift"]),
                           -128, 127) for q, v in zip(model["state"], state_mm)]
        x = np.concatenate([features, np.array(state_q, dtype=np.int64)])

    def dot(w, x, zp, state):
        n = x.size
        acc = w[:, :n] @ (x - zp)
        if state.size:
            acc = acc + np.floor_divide(w[:, n:] @ (state - 256 * zp) + 128, 256)
        return acc

    for rec in model["hidden"]:
        w, _, _, _ = layer_arrays(np, rec, rec["out_features"])
        x = requant(dot(w, x, zp, state), rec, rec["out_features"])
        state = np.zeros(0, dtype=np.int64)
        zp = rec["output"]["zero_point"]
    head = model["action_head"]
    w, _, _, _ = layer_arrays(np, head, 15)
    if model["version"] >= 2:
        # int16 logits, zero point 0.
        _, bias, m, s = layer_arrays(np, head, 15)
        logits = np.clip(rescale(np, dot(w, x, zp, state) + bias, m, s), -32768, 32767)
        return head["output"]["scale"] * logits
    logits = requant(dot(w, x, zp, state), head, 15)
    return head["output"]["scale"] * (logits - head["output"]["zero_point"])


# ---------------------------------------------------------------------------------------------
# Observations, timing


def observations(np, model, count, seed):
    """Boxes on flat ground and a state (as the Rust benchmark), metres, kept inside the file's
    input ranges (`scale * (q - zero_point)` for q in -128..127) so that the int8 path does not
    saturate where the float graph does not."""
    def span(quant, scale=None):
        scale = quant["scale_m"] if scale is None else scale
        return (scale * (-128 - quant["zero_point"]), scale * (127 - quant["zero_point"]))

    rng = np.random.default_rng(seed)
    rows, cols = model["input"]["rows"], model["input"]["cols"]
    top = min(0.45, span(model["input"]["height"])[1])
    out = []
    for _ in range(count):
        height = np.zeros((rows, cols), dtype=np.float32)
        for _ in range(4):
            r0, c0 = rng.integers(0, rows - 4), rng.integers(0, cols - 4)
            height[r0:r0 + 4, c0:c0 + 4] = rng.uniform(min(0.05, top), top)
        state = np.array([rng.uniform(*span(q, state_grid(model, q)[0])) for q in model["state"]],
                         dtype=np.float32)
        out.append((height, state))
    return out


def session(ort, path):
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def latency_us(run, seconds):
    """Median over batches of the mean time per call, in microseconds: (wall clock, CPU time of
    this process). CPU time is what to compare on a shared machine: it leaves out the time the
    process waited for a core (onnxruntime runs on this thread: 1 intra-op thread)."""
    for _ in range(200):
        run()
    start = time.perf_counter()
    calls = 0
    while time.perf_counter() - start < 0.2:
        run()
        calls += 1
    batch = max(10, calls)
    wall, cpu = [], []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(wall) < 5:
        t0, c0 = time.perf_counter_ns(), time.process_time_ns()
        for _ in range(batch):
            run()
        wall.append((time.perf_counter_ns() - t0) / batch / 1000.0)
        cpu.append((time.process_time_ns() - c0) / batch / 1000.0)
    wall.sort()
    cpu.sort()
    return wall[len(wall) // 2], cpu[len(cpu) // 2]


def runtime_cpu_us(weights, count):
    """CPU (user) time per decision of the Rust runtime, per kernel, from the `decisions` example:
    a run of `count` decisions minus a run of 0, as children's rusage."""
    import resource

    subprocess.check_call(["cargo", "build", "--release", "-q", "-p", "wheelleg-trainer",
                           "--example", "decisions"], cwd=ROOT)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
    binary = os.path.join(target, "release", "examples", "decisions")

    def user(*args):
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
        subprocess.check_call([binary, *args], stdout=subprocess.DEVNULL)
        return resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - before

    out = {}
    for kernel, n in (("avx2", count), ("scalar", count // 5), ("f32", count // 100)):
        extra = [weights] if kernel != "f32" else []
        try:
            base = user(kernel, "0", *extra)
            out[kernel] = (user(kernel, str(n), *extra) - base) / n * 1e6
        except subprocess.CalledProcessError:
            print(f"runtime kernel {kernel} not run (not supported here)")
    return out


def criterion_estimates(target_dir):
    out = {}
    base = os.path.join(target_dir, "criterion", "decision")
    if not os.path.isdir(base):
        return out
    for name in sorted(os.listdir(base)):
        path = os.path.join(base, name, "new", "estimates.json")
        if os.path.exists(path):
            with open(path) as f:
                out[name] = json.load(f)["median"]["point_estimate"] / 1000.0
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--weights", default=None,
                        help="a .wlw file (default: weights/policy.wlw, else a random policy)")
    parser.add_argument("--seconds", type=float, default=2.0, help="timing per configuration")
    parser.add_argument("--venv", default=os.path.join(ROOT, ".venv-onnx"))
    parser.add_argument("--cargo-bench", action="store_true",
                        help="run the runtime's criterion benchmark right after and print ratios")
    parser.add_argument("--runtime-cpu", type=int, default=0, metavar="N",
                        help="also measure the runtime's CPU time per decision over N decisions "
                             "(decisions example; N/5 scalar, N/100 trainer float forward)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = parser.parse_args()
    ensure_venv(args.venv)

    import numpy as np
    import onnxruntime as ort
    from onnxruntime.quantization import (CalibrationDataReader, QuantFormat, QuantType,
                                          quantize_static)

    weights = args.weights
    if weights is None:
        shipped = os.path.join(ROOT, "weights", "policy.wlw")
        weights = shipped if os.path.exists(shipped) else None
    work = tempfile.mkdtemp(prefix="wheelleg-onnx-")
    if weights is None:
        weights = os.path.join(work, "random.wlw")
        print("weights/policy.wlw not found: using a random policy (trainer/examples/random_policy.rs)")
        subprocess.check_call(["cargo", "run", "--release", "-q", "-p", "wheelleg-trainer",
                               "--example", "random_policy", "--", weights], cwd=ROOT)
    with open(weights, "rb") as f:
        model = parse_wlw(f.read())
    layers = dequantize(np, model)
    float_path = os.path.join(work, "policy_f32.onnx")
    build_onnx(np, model, layers, float_path)

    calib = observations(np, model, 256, seed=1)
    held_out = observations(np, model, 200, seed=2)

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.items = iter(calib)

        def get_next(self):
            item = next(self.items, None)
            if item is None:
                return None
            h, s = item
            return {"height": h[None, None], "state": s[None]}

    int8_paths = {}
    for fmt_name, fmt in (("qdq", QuantFormat.QDQ), ("qoperator", QuantFormat.QOperator)):
        path = os.path.join(work, f"policy_int8_{fmt_name}.onnx")
        quantize_static(float_path, path, Reader(), quant_format=fmt, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
        int8_paths[fmt_name] = path
    overhead_path = os.path.join(work, "identity.onnx")
    identity_graph(overhead_path)

    sessions = {"onnxruntime_f32": session(ort, float_path)}
    for name, path in int8_paths.items():
        sessions[f"onnxruntime_int8_{name}"] = session(ort, path)

    # Checks: float graph vs the file's integer semantics; int8 graphs' greedy agreement.
    err, mag, agree = [], [], {name: 0 for name in sessions}
    for h, s in held_out:
        feeds = {"height": h[None, None], "state": s[None]}
        ref = sessions["onnxruntime_f32"].run(["logits"], feeds)[0][0]
        mm_h = np.clip(np.round(h * 1000), -32768, 32767).astype(np.int64).reshape(-1)
        mm_s = np.round(s.astype(np.float64) * 1000).astype(np.int64)
        q = int8_forward(np, model, mm_h, mm_s)
        err.append(np.abs(q - ref).mean())
        mag.append(np.abs(ref).mean())
        greedy = ref.reshape(5, 3).argmax(1)
        agree["onnxruntime_f32"] += int((q.reshape(5, 3).argmax(1) == greedy).sum())
        for name in int8_paths:
            out = sessions[f"onnxruntime_int8_{name}"].run(["logits"], feeds)[0][0]
            agree[f"onnxruntime_int8_{name}"] += int((out.reshape(5, 3).argmax(1) == greedy).sum())
    print(f"weights: {weights}")
    # About 1-3% of the logits when the graph and the reader are right; the greedy agreement is
    # lower on these synthetic observations than on rollouts (more near ties).
    print(f"check: mean |int8 reference - onnx float| logit {np.mean(err):.4g} "
          f"(mean |logit| {np.mean(mag):.4g}); greedy agreement with onnx float per head: "
          + ", ".join(f"{'int8 reference (.wlw semantics)' if n == 'onnxruntime_f32' else n} "
                      f"{100.0 * a / (5 * len(held_out)):.1f}%" for n, a in agree.items()))

    h, s = held_out[0]
    feeds = {"height": h[None, None], "state": s[None]}
    overhead = session(ort, overhead_path)
    x = np.zeros((1, 4), dtype=np.float32)
    wall, cpu = {}, {}
    wall["python_run_overhead"], cpu["python_run_overhead"] = latency_us(
        lambda: overhead.run(None, {"x": x}), args.seconds)
    for name, sess in sessions.items():
        wall[name], cpu[name] = latency_us(lambda sess=sess: sess.run(None, feeds), args.seconds)
    print(f"onnxruntime {ort.__version__}, CPUExecutionProvider, 1 thread, batch 1 (microseconds "
          "per decision; 'net' = minus the Python call overhead)")
    print(f"{'configuration':<28} {'wall':>8} {'wall net':>9} {'CPU':>8} {'CPU net':>9}")
    for name in wall:
        over = name != "python_run_overhead"
        print(f"{name:<28} {wall[name]:>8.1f} {wall[name] - over * wall['python_run_overhead']:>9.1f} "
              f"{cpu[name]:>8.1f} {cpu[name] - over * cpu['python_run_overhead']:>9.1f}")
    figures = {f"{k}_wall": v for k, v in wall.items()}
    figures.update({f"{k}_cpu": v for k, v in cpu.items()})

    if args.runtime_cpu:
        runtime = runtime_cpu_us(weights, args.runtime_cpu)
        figures.update({f"runtime_{k}_cpu": v for k, v in runtime.items()})
        print("\nruntime CPU time per decision (decisions example, same window) and ratios "
              "onnxruntime CPU net / runtime:")
        for name, us in runtime.items():
            ratios = ", ".join(
                f"{k.replace('onnxruntime_', '')} x{(cpu[k] - cpu['python_run_overhead']) / us:.2f}"
                for k in sessions)
            print(f"  {name:<8} {us:>9.1f} us   {ratios}")

    if args.cargo_bench:
        target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
        subprocess.check_call(["nice", "-n", "10", "cargo", "bench", "-p", "wheelleg-runtime",
                               "--bench", "inference", "--", "decision/"], cwd=ROOT)
        runtime = criterion_estimates(target)
        figures.update({f"runtime_{k}": v for k, v in runtime.items()})
        print("\nruntime (criterion median, same window) and ratios onnxruntime / runtime "
              "(onnxruntime net of the Python call overhead):")
        for name, us in runtime.items():
            ratios = ", ".join(
                f"{k.replace('onnxruntime_', '')} x{(wall[k] - wall['python_run_overhead']) / us:.2f}"
                for k in sessions)
            print(f"  {name:<42} {us:>9.1f} us   {ratios}")
    if args.json:
        print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
