//! The check image on QEMU's mps2-an386 (Cortex-M4F): boots, checks the weights file, then runs
//! the check harness of scripts/mcu.sh, which the production image (`src/production/`) leaves
//! out. It decides on every recorded observation of `decisions.bin` and writes each decision to `decisions.out`, then drives the recorded
//! episode of `episode.bin` (decisions, the 100 Hz setpoint stream, the axes' feedback) and
//! writes its frames to `episode.frames.out` and its decisions to `episode.decisions.out`; the
//! host compares both with its own. On the console it reports what it counted: instructions
//! (QEMU's `-icount shift=0` clock) and the peak stack (by painting).
#![no_std]
#![no_main]

mod kernels;
mod qemu;

use core::arch::asm;
use core::mem::MaybeUninit;
use core::panic::PanicInfo;

use cortex_m_rt::entry;
use wheelleg_controller::control::{Control, ControlError};
use wheelleg_controller::link::{read_observation, Buffer};
use wheelleg_controller::stack::{
    ControllerDecider, DecisionRecord, Observation, Stack, ROW_ELEMENTS, WINDOW_BYTES, WORK_BYTES,
};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::Kernel;

use qemu::{tag, Clock, ReplayBoard, ReplayCan, Uart};
use wheelleg_controller::semihosting::{exit, File, Mode};

/// The policy's weights (weights/policy.wlw, or the file WHEELLEG_WEIGHTS named at build:
/// build.rs), in flash, word-aligned so that the kernels may load 4 weights at once.
#[repr(C, align(4))]
struct Aligned<T: ?Sized>(T);
static WEIGHTS: &Aligned<[u8]> = &Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/policy.wlw")));

/// Header of the decisions file: magic, version, records, window (side, cell in um, first
/// row, rows, first column, columns).
const HEADER_BYTES: usize = 4 * 10;
const DECISIONS_MAGIC: &[u8; 4] = b"WLDV";
const EPISODE_MAGIC: &[u8; 4] = b"WLEP";
const VERSION: u32 = 1;
/// Pattern of the painted stack.
const PAINT: u32 = 0xC0DE_5AFE;

static WORK: Buffer<[i8; WORK_BYTES]> = Buffer::new([0; WORK_BYTES]);
static ROW: Buffer<[i16; ROW_ELEMENTS]> = Buffer::new([0; ROW_ELEMENTS]);
static OBSERVATION: Buffer<Observation> = Buffer::new(Observation::new());
static DECIDER: Buffer<ControllerDecider> = Buffer::new(ControllerDecider::new());
/// In `.uninit`: neither zeroed at start-up nor given initial bytes in flash (the boot check
/// writes it).
#[link_section = ".uninit.STACK"]
static STACK: Buffer<MaybeUninit<Stack<'static, 'static>>> = Buffer::new(MaybeUninit::uninit());

/// The boot check: the weights file parsed and checked into the static `slot` (in a frame of
/// its own, popped before the first decision).
#[inline(never)]
fn boot(
    slot: &'static mut MaybeUninit<Stack<'static, 'static>>,
    decider: &'static mut ControllerDecider,
) -> Option<&'static mut Stack<'static, 'static>> {
    let stack = Stack::new(&WEIGHTS.0, decider).ok()?;
    Some(slot.write(stack))
}

/// Interrupts of the vector table: the 32 of QEMU's mps2-an386 (CMSDK peripherals), none
/// used (the controller polls its peripherals), each parked in a loop. A real board's HAL
/// crate provides its own table (102 entries on an STM32G431).
#[link_section = ".vector_table.interrupts"]
#[no_mangle]
static __INTERRUPTS: [unsafe extern "C" fn(); 32] = [unused_interrupt; 32];

/// An interrupt nothing enabled: stop here.
unsafe extern "C" fn unused_interrupt() {
    loop {
        // SAFETY: `wfi` only waits for an interrupt.
        unsafe { asm!("wfi", options(nomem, nostack)) };
    }
}

#[panic_handler]
fn panic(_info: &PanicInfo) -> ! {
    exit(101)
}

extern "C" {
    static __sheap: u32;
    static _stack_start: u32;
}

/// Fills the free stack (from the end of `.bss` to a little below the current stack pointer)
/// with [`PAINT`], so that [`peak_stack_bytes`] can find the deepest word ever written.
#[inline(never)]
fn paint_stack() {
    let bottom = core::ptr::addr_of!(__sheap) as usize;
    let sp: usize;
    // SAFETY: reads the stack pointer.
    unsafe { asm!("mov {}, sp", out(reg) sp, options(nomem, nostack)) };
    let mut at = bottom;
    // Leave 64 bytes below this frame untouched: this function's own.
    while at + 64 < sp {
        // SAFETY: `[__sheap, sp - 64)` is RAM that no live object uses: below every frame,
        // above every static.
        unsafe { core::ptr::write_volatile(at as *mut u32, PAINT) };
        at += 4;
    }
}

/// Bytes of stack used at the deepest so far: from the top of RAM down to the lowest word
/// no longer painted.
fn peak_stack_bytes() -> usize {
    let bottom = core::ptr::addr_of!(__sheap) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut at = bottom;
    // SAFETY: reads the painted region, word by word, below the live frames.
    while at < top && unsafe { core::ptr::read_volatile(at as *const u32) } == PAINT {
        at += 4;
    }
    top - at
}

fn u32_at(bytes: &[u8], word: usize) -> u32 {
    match bytes.get(4 * word..4 * word + 4) {
        Some(&[a, b, c, d]) => u32::from_le_bytes([a, b, c, d]),
        _ => 0,
    }
}

/// What the harness counts.
#[derive(Default)]
struct Counts {
    decisions: u64,
    infer_instructions: u64,
    decide_instructions: u64,
    max_decision_instructions: u64,
    ticks: u64,
    tick_instructions: u64,
    scalar_infer_instructions: u64,
    kernel_mismatches: u64,
}

#[entry]
fn main() -> ! {
    paint_stack();
    let mut uart = Uart::new();
    let clock = Clock::start();

    // The clock's calibration: a loop of exactly 2 instructions per turn.
    let turns: u32 = 500_000;
    let start = clock.now();
    // SAFETY: a register-only countdown loop.
    unsafe {
        asm!("1:", "subs {n}, #1", "bne 1b", n = inout(reg) turns => _, options(nomem, nostack));
    }
    let calibration = clock.instructions_since(start);

    let (Some(decider), Some(slot)) = (DECIDER.take(), STACK.take()) else {
        exit(5)
    };
    let start = clock.now();
    let stack = boot(slot, decider);
    let boot_instructions = clock.instructions_since(start);
    let Some(stack) = stack else {
        uart.write(b"WLMCU error=weights\n");
        exit(2)
    };
    uart.write(b"WLMCU ");
    uart.field("calibration_instructions", calibration);
    uart.field("calibration_expected", 2 * u64::from(turns));
    uart.field("instructions_boot_check", boot_instructions);
    uart.field(
        "input_quantization_mismatches",
        kernels::input_quantization_mismatches(),
    );
    uart.write(b"\n");

    let (Some(work), Some(row), Some(observation)) = (WORK.take(), ROW.take(), OBSERVATION.take())
    else {
        exit(5)
    };
    let mut counts = Counts::default();
    let status = run_decisions(stack, observation, work, row, &clock, &mut counts);
    if let Err(what) = status {
        uart.write(b"WLMCU error=");
        uart.write(what);
        uart.write(b"\n");
        exit(3)
    }
    let status = run_episode(stack, observation, work, row, &clock, &mut counts);
    match status {
        Ok((ticks, sent)) => {
            uart.write(b"WLMCU ");
            uart.field("episode_ticks", u64::from(ticks));
            uart.field("episode_frames", u64::from(sent));
            uart.write(b"\n");
        }
        Err(what) => {
            uart.write(b"WLMCU error=");
            uart.write(what);
            uart.write(b"\n");
            exit(4)
        }
    }

    uart.write(b"WLMCU ");
    uart.field("decisions", counts.decisions);
    uart.field("infer_instructions", counts.infer_instructions);
    uart.field("decide_instructions", counts.decide_instructions);
    uart.field(
        "max_decision_instructions",
        counts.max_decision_instructions,
    );
    uart.field("ticks", counts.ticks);
    uart.field("tick_instructions", counts.tick_instructions);
    uart.field(
        "scalar_infer_instructions",
        counts.scalar_infer_instructions,
    );
    uart.field("kernel_mismatches", counts.kernel_mismatches);
    uart.field("stack_bytes", peak_stack_bytes() as u64);
    uart.write(b"\n");
    exit(0)
}

/// Decides on every observation of `decisions.bin`, writing each record to `decisions.out`.
#[inline(never)]
fn run_decisions(
    stack: &mut Stack<'_, '_>,
    observation: &mut Observation,
    work: &mut [i8; WORK_BYTES],
    row: &mut [i16; ROW_ELEMENTS],
    clock: &Clock,
    counts: &mut Counts,
) -> Result<(), &'static [u8]> {
    let window_bytes = 2 * stack.window().cells();
    let mut input =
        File::open(b"decisions.bin\0", Mode::Read).ok_or(b"open decisions.bin".as_slice())?;
    let mut output =
        File::open(b"decisions.out\0", Mode::Write).ok_or(b"open decisions.out".as_slice())?;
    let mut header = [0u8; HEADER_BYTES];
    if !input.read_exact(&mut header) || header.get(..4) != Some(DECISIONS_MAGIC.as_slice()) {
        return Err(b"decisions.bin header");
    }
    check_header(&header, stack)?;
    let records = u32_at(&header, 2);
    for _ in 0..records {
        let flags = read_observation(&mut |buf| input.read_exact(buf), observation)
            .ok_or(b"decisions.bin record".as_slice())?;
        if flags & 1 != 0 {
            stack.reset();
        }
        let record = decide_one(
            stack,
            observation,
            work,
            row,
            window_bytes,
            &mut |buf| input.read_exact(buf),
            clock,
            counts,
        )?;
        if !output.write_all(&record.to_bytes()) {
            return Err(b"decisions.out write");
        }
    }
    Ok(())
}

/// Drives the recorded episode of `episode.bin` period by period; returns the periods run and
/// the frames sent.
#[inline(never)]
fn run_episode(
    stack: &mut Stack<'_, '_>,
    observation: &mut Observation,
    work: &mut [i8; WORK_BYTES],
    row: &mut [i16; ROW_ELEMENTS],
    clock: &Clock,
    counts: &mut Counts,
) -> Result<(u32, u32), &'static [u8]> {
    let window_bytes = 2 * stack.window().cells();
    let mut input =
        File::open(b"episode.bin\0", Mode::Read).ok_or(b"open episode.bin".as_slice())?;
    let frames = File::open(b"episode.frames.out\0", Mode::Write)
        .ok_or(b"open episode.frames.out".as_slice())?;
    let mut decisions = File::open(b"episode.decisions.out\0", Mode::Write)
        .ok_or(b"open episode.decisions.out".as_slice())?;
    let mut header = [0u8; 16];
    if !input.read_exact(&mut header) || header.get(..4) != Some(EPISODE_MAGIC.as_slice()) {
        return Err(b"episode.bin header");
    }
    if u32_at(&header, 1) != VERSION {
        return Err(b"episode.bin version");
    }
    let start = LegConfig {
        clearance_m: f32::from_bits(u32_at(&header, 2)),
        track_m: f32::from_bits(u32_at(&header, 3)),
    };
    stack.reset();
    let mut board = ReplayBoard {
        can: ReplayCan::new(input, frames),
    };
    let mut control: Control<CanFrame> = Control::new(&stack.robot(), start);
    loop {
        let Some(entry) = board.can.next_tag() else {
            return Err(b"episode.bin truncated");
        };
        let ticks = board.can.ticks;
        match entry {
            tag::END => break,
            tag::STARTUP => {
                let start = clock.now();
                control.start_up(&mut board).map_err(|e| match e {
                    ControlError::StartupRefused(_) => {
                        b"start-up refused by the roll call".as_slice()
                    }
                    _ => b"start-up failed".as_slice(),
                })?;
                counts.tick_instructions += clock.instructions_since(start);
            }
            tag::DECISION => {
                let can = &mut board.can;
                read_observation(&mut |buf| can.read(buf), observation)
                    .ok_or(b"episode.bin record".as_slice())?;
                // Counted apart: part 1 measures decisions.
                let mut episode_counts = Counts::default();
                let record = decide_one(
                    stack,
                    observation,
                    work,
                    row,
                    window_bytes,
                    &mut |buf| can.read(buf),
                    clock,
                    &mut episode_counts,
                )?;
                if !decisions.write_all(&record.to_bytes()) {
                    return Err(b"episode.decisions.out write");
                }
                let start = clock.now();
                // An action the legs cannot take is not sent, as on the host.
                let _ = control.step(&mut board, record.action());
                counts.tick_instructions += clock.instructions_since(start);
            }
            _ => return Err(b"episode.bin entry"),
        }
        counts.ticks += u64::from(board.can.ticks - ticks);
        if board.can.desync {
            return Err(b"episode: the controller's periods differ from the recording's");
        }
    }
    Ok((board.can.ticks, board.can.sent))
}

/// The decisions file's version and window must be the controller's own (words 1 and 4 to 9
/// of its header: version; side, cell in micrometres, first row, rows, first column, columns).
fn check_header(header: &[u8], stack: &Stack<'_, '_>) -> Result<(), &'static [u8]> {
    let window = stack.window();
    let expected = [
        (1, VERSION),
        (4, window.side as u32),
        (5, (window.cell_m * 1.0e6 + 0.5) as u32),
        (6, window.first_row as u32),
        (7, window.rows as u32),
        (8, window.first_col as u32),
        (9, window.cols as u32),
    ];
    if expected
        .iter()
        .all(|&(word, want)| u32_at(header, word) == want)
    {
        Ok(())
    } else {
        Err(b"decisions.bin: not this controller's version or fine window")
    }
}

/// One decision: inference, then the window is read into the same bytes, then the rule.
#[allow(clippy::too_many_arguments)]
fn decide_one(
    stack: &mut Stack<'_, '_>,
    observation: &Observation,
    work: &mut [i8; WORK_BYTES],
    row: &mut [i16; ROW_ELEMENTS],
    window_bytes: usize,
    read: &mut dyn FnMut(&mut [u8]) -> bool,
    clock: &Clock,
    counts: &mut Counts,
) -> Result<DecisionRecord, &'static [u8]> {
    let start = clock.now();
    let outputs = stack
        .infer(observation, work, row)
        .map_err(|_| b"inference".as_slice())?;
    let infer = clock.instructions_since(start);
    // The portable scalar kernel on the same observation: its outputs must be the fast
    // kernel's, bit for bit (`Outputs` compares every logit). Left out of a build for
    // tools/mcu_profile.sh, which counts the fast kernel alone.
    let fast = stack.policy().kernel();
    if option_env!("WHEELLEG_CHECK_FAST_ONLY").is_none() && stack.set_kernel(Kernel::Scalar).is_ok()
    {
        let start = clock.now();
        let reference = stack.infer(observation, work, row);
        counts.scalar_infer_instructions += clock.instructions_since(start);
        counts.kernel_mismatches += u64::from(reference != Ok(outputs));
        stack.set_kernel(fast).map_err(|_| b"kernel".as_slice())?;
    }
    // The window arrives after inference, into the bytes inference no longer needs.
    let window: &mut [u8] = bytes_of(work)
        .get_mut(..window_bytes.min(WINDOW_BYTES))
        .ok_or(b"window".as_slice())?;
    if !read(window) {
        return Err(b"window read");
    }
    let start = clock.now();
    let record = stack
        .decide(observation, &outputs, window)
        .map_err(|_| b"decision".as_slice())?;
    let decide = clock.instructions_since(start);
    counts.decisions += 1;
    counts.infer_instructions += infer;
    counts.decide_instructions += decide;
    counts.max_decision_instructions = counts.max_decision_instructions.max(infer + decide);
    Ok(record)
}

/// The work area's bytes as `u8` (the window's little-endian heights).
fn bytes_of(work: &mut [i8; WORK_BYTES]) -> &mut [u8; WORK_BYTES] {
    // SAFETY: `i8` and `u8` have the same size, alignment and validity (every bit pattern).
    unsafe { &mut *(work as *mut [i8; WORK_BYTES] as *mut [u8; WORK_BYTES]) }
}
