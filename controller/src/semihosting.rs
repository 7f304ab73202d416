//! Arm semihosting (the debugger's file and exit calls, `bkpt 0xAB`): how the check image reads
//! its test vectors, writes its results and ends the run in QEMU, and how the production image
//! built for the HIL's emulated clock takes its CAN adapter's bytes. A real board has no
//! debugger attached and uses its own links.

use core::arch::asm;

const SYS_OPEN: u32 = 0x01;
const SYS_CLOSE: u32 = 0x02;
const SYS_WRITE: u32 = 0x05;
const SYS_READ: u32 = 0x06;
const SYS_EXIT_EXTENDED: u32 = 0x20;
/// `ADP_Stopped_ApplicationExit`: the program ended by itself (with an exit status).
const APPLICATION_EXIT: u32 = 0x2_0026;

/// One semihosting call with its parameter block.
fn call(op: u32, block: &[usize]) -> isize {
    let result: u32;
    // SAFETY: `bkpt 0xAB` traps to the emulator, which reads the parameter block (valid for
    // the duration of the call) and writes only to the buffers it names, which the callers
    // pass as live slices of the right length.
    unsafe {
        asm!(
            "bkpt #0xAB",
            inout("r0") op => result,
            in("r1") block.as_ptr(),
            options(nostack),
        );
    }
    result as i32 as isize
}

/// An open host file.
pub struct File(usize);

/// How a file is opened.
#[derive(Clone, Copy)]
pub enum Mode {
    /// Read, binary.
    Read = 1,
    /// Write (truncate), binary.
    Write = 5,
}

impl File {
    /// Opens `name` (NUL-terminated) relative to the emulator's working directory.
    pub fn open(name: &[u8], mode: Mode) -> Option<File> {
        let len = name.len().saturating_sub(1);
        if name.last() != Some(&0) {
            return None;
        }
        let handle = call(SYS_OPEN, &[name.as_ptr() as usize, mode as usize, len]);
        usize::try_from(handle).ok().map(File)
    }

    /// Fills `buf` completely; false at the end of the file or on an error.
    pub fn read_exact(&mut self, buf: &mut [u8]) -> bool {
        let left = call(SYS_READ, &[self.0, buf.as_mut_ptr() as usize, buf.len()]);
        left == 0
    }

    /// Reads what is there into `buf`, waiting (in the host, at no cost to the emulated
    /// clock) until there is at least a byte; the bytes read, 0 at the end or on an error.
    pub fn read_some(&mut self, buf: &mut [u8]) -> usize {
        let left = call(SYS_READ, &[self.0, buf.as_mut_ptr() as usize, buf.len()]);
        usize::try_from(left).map_or(0, |left| buf.len().saturating_sub(left))
    }

    /// Writes all of `bytes`.
    pub fn write_all(&mut self, bytes: &[u8]) -> bool {
        call(SYS_WRITE, &[self.0, bytes.as_ptr() as usize, bytes.len()]) == 0
    }
}

impl Drop for File {
    fn drop(&mut self) {
        call(SYS_CLOSE, &[self.0]);
    }
}

/// Ends the emulation with `status` (QEMU exits with it).
pub fn exit(status: u32) -> ! {
    loop {
        call(
            SYS_EXIT_EXTENDED,
            &[APPLICATION_EXIT as usize, status as usize],
        );
    }
}
