//! A firmware-shaped program: no `std`, no allocator, its own panic handler. It links the C
//! library only for the process entry and `write`/`_exit`, as a microcontroller's startup code
//! would provide the entry. Linking `std` would fail the build with a duplicate `panic_impl`
//! lang item, and any use of `alloc` would fail it with "no global memory allocator found".
//!
//! It loads the weights file named by `WHEELLEG_POLICY` at build time, takes one decision on a
//! fixed observation and a second one as if the first had been refused (`decision::Decider`),
//! prints both action indices and exits with 0 (or prints the error, exits 1). Before that it
//! sends a CANSimple frame through the SLCAN encoder and line decoder, which must hand back the
//! same frame, so the serial-adapter codec is proven to link without `std` or `alloc` too.
#![no_std]
#![no_main]

use core::fmt::Write;
use core::panic::PanicInfo;

use wheelleg_runtime::arrival::{Arrival, DEFAULT_RADIUS_M};
use wheelleg_runtime::can::protocol::{encode, Message, NodeId};
use wheelleg_runtime::can::slcan::{encode_frame, Command, Decoder};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef, DEFAULT_MARGIN_M};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::DefaultPolicy;
use wheelleg_runtime::observation::HEIGHT_MAP_CELLS;
use wheelleg_runtime::robot::{Robot, WHEELLEG};

static WEIGHTS: &[u8] = include_bytes!(env!("WHEELLEG_POLICY"));

#[link(name = "c")]
extern "C" {
    fn write(fd: i32, buf: *const u8, count: usize) -> isize;
    fn _exit(status: i32) -> !;
}

/// Standard output through `write(2)`.
struct Stdout;

impl Write for Stdout {
    fn write_str(&mut self, text: &str) -> core::fmt::Result {
        // SAFETY: the pointer and length come from a valid `&str`.
        let written = unsafe { write(1, text.as_ptr(), text.len()) };
        if written == text.len() as isize {
            Ok(())
        } else {
            Err(core::fmt::Error)
        }
    }
}

#[panic_handler]
fn panic(_info: &PanicInfo) -> ! {
    // SAFETY: `_exit` ends the process; no state is left to tear down.
    unsafe { _exit(101) }
}

/// The prebuilt `core` for linux-gnu targets is compiled with unwinding and references this
/// symbol; with `panic = "abort"` nothing ever unwinds, so it is never called. (Firmware targets
/// such as thumbv7em-none-eabihf ship a `core` without it.)
#[no_mangle]
extern "C" fn rust_eh_personality() {}

/// The same observation as `trainer/examples/random_policy.rs`, in millimetres.
fn observation() -> ([[i16; 32]; 32], [i32; 4]) {
    let mut height_mm = [[0i16; 32]; 32];
    for row in height_mm.iter_mut().take(8).skip(2) {
        for cell in row.iter_mut().take(20).skip(12) {
            *cell = 200;
        }
    }
    (height_mm, [250, 400, 2000, 500])
}

/// A Set_Input_Vel frame for node 13 comes back unchanged from its SLCAN line.
fn slcan_round_trips() -> bool {
    let Some(node) = NodeId::new(13) else {
        return false;
    };
    let message = Message::SetInputVel {
        vel_turns_per_s: 2.5,
        torque_ff_nm: 0.0,
    };
    let Ok(frame) = encode::<CanFrame>(node, &message) else {
        return false;
    };
    let Ok(line) = encode_frame(&frame, None) else {
        return false;
    };
    let mut decoder = Decoder::new();
    let mut decoded = None;
    for &byte in line.as_bytes() {
        match decoder.feed(byte) {
            Ok(Some(command)) => decoded = Some(command),
            Ok(None) => {}
            Err(_) => return false,
        }
    }
    decoded
        == Some(Command::Frame {
            frame,
            timestamp_ms: None,
        })
}

#[no_mangle]
extern "C" fn main(_argc: i32, _argv: *const *const u8) -> i32 {
    if !slcan_round_trips() {
        let _ = writeln!(Stdout, "slcan round trip failed");
        return 1;
    }
    let (height_mm, state_mm) = observation();
    let result = DefaultPolicy::from_bytes(WEIGHTS)
        .map_err(|error| (error, None))
        .and_then(|policy| {
            policy
                .evaluate(height_mm.as_flattened(), &state_mm)
                .map_err(|error| (wheelleg_runtime::model::LoadError::Truncated, Some(error)))
        });
    match result {
        Ok(outputs) => {
            // The second decision meets the same observation again (the first was refused).
            let key = ObservationKey::of_mm(height_mm.as_flattened(), &state_mm);
            let mut decider: Decider = Decider::new();
            let first = decider.choose(key, &outputs.action_logits);
            let second = decider.choose(key, &outputs.action_logits);
            // The third with the collision guard, at the default pose.
            let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
            let legs = LegConfig {
                clearance_m: WHEELLEG.default_clearance_m,
                track_m: WHEELLEG.default_track_m,
            };
            let map: &[i16; HEIGHT_MAP_CELLS] = match height_mm.as_flattened().try_into() {
                Ok(map) => map,
                Err(_) => return 1,
            };
            let third = guard.choose(
                &mut decider,
                key,
                &outputs.action_logits,
                HeightMapRef::Millimetres(map),
                legs,
                Some(&Arrival::from_state_mm(&state_mm, DEFAULT_RADIUS_M, &Robot::WHEELLEG.actions)),
            );
            let _ = writeln!(
                Stdout,
                "{} {} {} {:?}",
                first.index(),
                second.index(),
                third.action.index(),
                third.level
            );
            0
        }
        Err((load, None)) => {
            let _ = writeln!(Stdout, "load error: {load}");
            1
        }
        Err((_, Some(infer))) => {
            let _ = writeln!(Stdout, "inference error: {infer}");
            1
        }
    }
}
