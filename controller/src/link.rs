//! What both images share around the decision stack: the once-only static buffers and the
//! observation record's wire format (flags, the 32 x 32 height map in `i16` millimetres, the
//! state in `i32` millimetres, all little-endian), the same on the observation link of the
//! production image and in the check image's vector files.

use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, Ordering};

use crate::stack::Observation;

/// A buffer in `.bss` handed out once, as a `&'static mut`: the large buffers live here
/// rather than in `main`'s frame, so that nothing copies them and their RAM shows in the
/// image's section sizes.
pub struct Buffer<T>(UnsafeCell<T>, AtomicBool);

// SAFETY: the only access is through `take`, which hands out the one reference at most once.
unsafe impl<T> Sync for Buffer<T> {}

impl<T> Buffer<T> {
    /// A buffer holding `value`, not yet handed out.
    pub const fn new(value: T) -> Buffer<T> {
        Buffer(UnsafeCell::new(value), AtomicBool::new(false))
    }

    /// The one reference to the buffer's value; `None` after the first call.
    // The one `&mut` comes from the cell, handed out once (the flag), as `singleton!` does.
    #[allow(clippy::mut_from_ref)]
    pub fn take(&'static self) -> Option<&'static mut T> {
        if self.1.swap(true, Ordering::AcqRel) {
            return None;
        }
        // SAFETY: the flag was clear, so no other reference was ever handed out.
        Some(unsafe { &mut *self.0.get() })
    }
}

/// Reads the fixed part of an observation record (flags, map, state) into `observation` with
/// `read` (which fills its buffer whole or returns `false`); returns the flags (bit 0: a new
/// episode starts).
pub fn read_observation(
    read: &mut dyn FnMut(&mut [u8]) -> bool,
    observation: &mut Observation,
) -> Option<u32> {
    let mut flags = [0u8; 4];
    // 64 cells at a time: a small buffer on the stack rather than the map's 2 KiB.
    let mut map = [0u8; 2 * 64];
    if !read(&mut flags) {
        return None;
    }
    for cells in observation.height_mm.chunks_mut(64) {
        let bytes = map.get_mut(..2 * cells.len())?;
        if !read(bytes) {
            return None;
        }
        for (cell, pair) in cells.iter_mut().zip(bytes.chunks_exact(2)) {
            *cell = i16::from_le_bytes([*pair.first()?, *pair.get(1)?]);
        }
    }
    for value in observation.state_mm.iter_mut() {
        let mut bytes = [0u8; 4];
        if !read(&mut bytes) {
            return None;
        }
        *value = i32::from_le_bytes(bytes);
    }
    Some(u32::from_le_bytes(flags))
}
