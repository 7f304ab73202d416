//! Worst-case stack and instruction count of one decision (`Policy::act`, scratch on the
//! stack), for the bound written in docs/robustness.md.
//!
//! Stack: measured by painting, the way firmware does it. A function fills a large stack array
//! with a pattern and returns; the decision runs from the same call depth and overwrites the
//! part of that region its frames reach; a second function counts how much of the pattern is
//! left at the far (low-address) end. The first 256 bytes below the caller are not painted
//! (the painting function's own frame lives there) and are added back, so the figure printed
//! is an upper bound; an empty probe checks that calling one costs nothing measurable.
//!
//! Time: the kernels have no data-dependent branches (clamps are min/max, argmax is a fixed
//! 3-way compare), so one decision's instruction count is the same for every input.
//! `valgrind --tool=callgrind target/release/examples/stack_probe WEIGHTS INPUT N KERNEL` for
//! each INPUT (`zeros`, `ramp`, `extreme`) shows it; `tools/stack_time_bound.sh` does both.
//!
//! Usage: `stack_probe WEIGHTS.wlw [INPUT N KERNEL]`: without INPUT, prints the stack of each
//! input and kernel; with it, runs N decisions on that input with KERNEL (`scalar`, `avx2`)
//! for callgrind and prints a checksum.
// A host measuring tool: failing loudly on a bad argument is its whole error handling, and
// reading the painted stack below the live frames needs raw pointers.
#![allow(
    unsafe_code,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    clippy::std_instead_of_core
)]

use std::hint::black_box;
use wheelleg_runtime::model::{DefaultPolicy, Kernel};
use wheelleg_runtime::observation::{HEIGHT_MAP_SIDE, STATE_LEN};

/// Bytes painted: far more than a decision needs (its scratch alone is 10 KiB).
const PAINT: usize = 128 * 1024;
const PATTERN: u8 = 0xA5;

type HeightMap = [[i16; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE];

/// Distance below a small frame's local where painting starts: well past the frame itself.
const SKIP: usize = 256;

// Painting works below its own small frame through a raw pointer rather than in a large local
// array: a frame larger than a page gets stack probes, which write a zero word into every page
// of it and would cut the painted region into 4 KiB pieces. Returns the deepest painted byte.
#[inline(never)]
fn paint() -> *const u8 {
    let marker = 0u8;
    // An address, not a pointer derived from `marker`: the bytes painted are no part of
    // `marker`, and a pointer with its provenance would let the compiler drop the writes.
    let top = std::ptr::addr_of!(marker) as usize;
    for i in SKIP..PAINT {
        let byte = std::ptr::with_exposed_provenance_mut::<u8>(top - i);
        // SAFETY: below the live frames of this thread, inside its 4 MiB stack; nothing else
        // runs on it while the loop runs.
        unsafe { std::ptr::write_volatile(byte, PATTERN) };
    }
    black_box(&marker);
    std::ptr::with_exposed_provenance(top - (PAINT - 1))
}

/// Painted bytes, from the deepest one up, that no frame has written since [`paint`].
#[inline(never)]
fn untouched(deepest: *const u8) -> usize {
    let mut n = 0;
    // SAFETY: the region [`paint`] wrote, still below this small frame.
    while n < PAINT - SKIP && unsafe { std::ptr::read_volatile(deepest.wrapping_add(n)) } == PATTERN
    {
        n += 1;
    }
    n
}

/// What a probe runs: one decision, or nothing (to calibrate).
type Probe = fn(&DefaultPolicy<'_>, &HeightMap, &[i32; STATE_LEN]);

/// One decision, in a frame of its own below the caller's: a closure here was inlined into
/// the caller, whose frame (with the 10 KiB scratch in it) then lay above the painted region.
#[inline(never)]
fn decide(policy: &DefaultPolicy<'_>, map: &HeightMap, state: &[i32; STATE_LEN]) {
    black_box(policy.act(black_box(map), black_box(state)).unwrap());
}

#[inline(never)]
fn nothing(_: &DefaultPolicy<'_>, _: &HeightMap, _: &[i32; STATE_LEN]) {
    black_box(0u8);
}

/// Stack bytes `probe` uses more than [`SKIP`] below the caller's frame.
#[inline(never)]
fn stack_of(
    policy: &DefaultPolicy<'_>,
    map: &HeightMap,
    state: &[i32; STATE_LEN],
    probe: Probe,
) -> usize {
    let deepest = paint();
    probe(policy, map, state);
    PAINT - SKIP - untouched(deepest)
}

fn input(name: &str) -> (HeightMap, [i32; STATE_LEN]) {
    let n = HEIGHT_MAP_SIDE;
    match name {
        "zeros" => ([[0; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE], [0; STATE_LEN]),
        "ramp" => {
            let mut map = [[0i16; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE];
            for (r, row) in map.iter_mut().enumerate() {
                for (c, cell) in row.iter_mut().enumerate() {
                    *cell = ((r * n + c) % 400) as i16;
                }
            }
            (map, [120, 360, 800, -150])
        }
        "extreme" => (
            [[i16::MAX; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE],
            [i32::MAX, i32::MIN, i32::MAX, i32::MIN],
        ),
        other => panic!("unknown input {other:?} (zeros, ramp, extreme)"),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let bytes = std::fs::read(
        args.first()
            .expect("usage: stack_probe WEIGHTS.wlw [INPUT N]"),
    )
    .expect("read weights file");
    // A thread with a known, roomy stack, so that the painted region exists.
    std::thread::Builder::new()
        .stack_size(4 << 20)
        .spawn(move || run(&bytes, &args))
        .unwrap()
        .join()
        .unwrap();
}

fn run(bytes: &[u8], args: &[String]) {
    let mut policy = DefaultPolicy::from_bytes(bytes).unwrap();
    if let [_, name, count, kernel] = args {
        let kernel = match kernel.as_str() {
            "scalar" => Kernel::Scalar,
            "avx2" => Kernel::Avx2,
            other => panic!("unknown kernel {other:?} (scalar, avx2)"),
        };
        policy
            .set_kernel(kernel)
            .expect("kernel not supported on this CPU");
        let (map, state) = input(name);
        let count: usize = count.parse().unwrap();
        let mut checksum = 0usize;
        for _ in 0..count {
            let action = policy.act(black_box(&map), black_box(&state)).unwrap();
            checksum += action.index();
        }
        println!("{count} decisions on {name}: checksum {checksum}");
        return;
    }
    let (map, state) = input("zeros");
    let overhead = stack_of(&policy, &map, &state, black_box(nothing));
    // The bound adds back the bytes just below the caller that are not painted.
    println!("calibration (empty probe): {overhead} B below the unpainted {SKIP} B");
    let mut kernels = vec![Kernel::Scalar];
    if policy.set_kernel(Kernel::Avx2).is_ok() {
        kernels.push(Kernel::Avx2);
    }
    for kernel in kernels {
        policy.set_kernel(kernel).unwrap();
        for name in ["zeros", "ramp", "extreme"] {
            let (map, state) = input(name);
            let used = stack_of(&policy, &map, &state, black_box(decide));
            println!("{kernel:?} {name:<8} stack <= {:>6} B", used + SKIP);
        }
    }
}
