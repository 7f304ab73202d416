# Shared by the callgrind measuring scripts (source it after setting `bin`, the binary to run).
# Sets `out` (a temporary folder removed on exit), `kernels` (the int8 kernels this CPU runs)
# and defines `refs ARGS...`: the instructions ("I refs") of one run of `$bin ARGS...`.
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT

refs() {
    valgrind --tool=callgrind --callgrind-out-file="$out/cg.out" "$bin" "$@" 2>&1 >/dev/null |
        sed -n 's/.*I *refs: *\([0-9,]*\).*/\1/p' | tr -d ,
}

kernels="scalar"
if grep -qw avx2 /proc/cpuinfo 2>/dev/null; then kernels="scalar avx2"; fi
