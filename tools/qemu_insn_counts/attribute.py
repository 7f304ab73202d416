#!/usr/bin/env python3
"""Attributes the per-instruction counts of insn_counts.c to the source of an ELF.

    attribute.py ELF COUNTS DECISIONS [ROWS]

Prints instructions per decision (the counts divided by DECISIONS) of the inference: by what
`forward_in` calls at each of its lines (functions inlined into it included), by the out-of-line
functions of the model code and the assembly loops, then by innermost source line. The inline
chains come from the ELF's debug information (llvm-addr2line -i). Model functions the check
harness also calls outside inference (its input quantization test) are counted with it.
"""
import collections
import subprocess
import sys


def main():
    elf, counts_path, decisions = sys.argv[1], sys.argv[2], float(sys.argv[3])
    rows = int(sys.argv[4]) if len(sys.argv) > 4 else 30
    counts = []
    with open(counts_path) as file:
        for line in file:
            address, count = line.split()
            counts.append((int(address, 16), int(count)))
    lines = subprocess.run(
        ["llvm-addr2line", "-e", elf, "-f", "-C", "-i", "-a"],
        input="\n".join(hex(a) for a, _ in counts),
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split("\n")
    chains, chain = [], None
    for line in lines:
        if line.startswith("0x"):
            chain = []
            chains.append(chain)
        elif chain is not None and line:
            chain.append(line)
    by_call = collections.Counter()
    by_line = collections.Counter()
    for (_, count), chain in zip(counts, chains):
        # (function, file:line) pairs, innermost first.
        frames = [(chain[i], chain[i + 1].split("/")[-1]) for i in range(0, len(chain) - 1, 2)]
        at = [i for i, (function, _) in enumerate(frames) if "infer::forward_in" in function]
        if at:
            i = at[-1]
            callee = frames[i - 1][0][:70] if i > 0 else ""
            by_call[f"{frames[i][1]} {callee}"] += count
        elif frames and ("wheelleg_dsp" in frames[-1][0] or "runtime::model" in frames[-1][0]):
            by_call[f"[function] {frames[-1][0][:90]}"] += count
        else:
            continue
        if frames[-1][0].startswith("wheelleg_dsp"):
            # global_asm! has no line table of its own.
            by_line[f"[assembly] {frames[-1][0]}"] += count
        else:
            by_line[f"{frames[0][1]} {frames[0][0][:60]}"] += count
    total = sum(by_call.values())
    print(f"{total / decisions:>10,.0f}  inference, per decision")
    for key, count in by_call.most_common(rows):
        print(f"{count / decisions:>10,.0f}  {key}")
    print("--- by innermost source line")
    for key, count in by_line.most_common(rows):
        print(f"{count / decisions:>10,.0f}  {key}")


if __name__ == "__main__":
    main()
