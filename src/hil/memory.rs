//! The production image's RAM as it runs, measured from outside the firmware: QEMU paints the
//! free RAM between the statics and the top of the stack before the core starts (a loader
//! device, so the image carries no painting code: its flash has no room for any), and after
//! the episode the monitor saves that RAM to a file. The stack reached down to the lowest word
//! no longer painted. The check image paints itself the same way (`controller/src/check`).

use std::path::{Path, PathBuf};

use object::{Object, ObjectSymbol};

use super::HilError;

/// The painted word; the check image's pattern.
pub const PAINT: u32 = 0xC0DE_5AFE;

/// Where the image's statics end and its stack begins, from the ELF's link symbols
/// (cortex-m-rt's `__sdata`, `__sheap` and `_stack_start`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RamLayout {
    /// First byte of RAM the statics use (`.data`, then `.bss` and `.uninit`).
    pub statics_start: u32,
    /// First byte past the statics: the lowest the stack may reach.
    pub stack_limit: u32,
    /// One past the stack's top (the initial stack pointer).
    pub stack_top: u32,
    /// The firmware's `BUSIEST_PERIOD_COUNTS`: the most SysTick counts of work in one control
    /// period since boot.
    pub busiest_period_counts: u32,
}

impl RamLayout {
    /// The layout of the ELF image at `image`.
    pub fn of_image(image: &Path) -> Result<RamLayout, HilError> {
        let bytes = std::fs::read(image)
            .map_err(|e| HilError::Io(format!("reading {}: {e}", image.display())))?;
        let file = object::File::parse(&*bytes)
            .map_err(|e| HilError::Io(format!("{} is no ELF image: {e}", image.display())))?;
        let symbol = |name: &str| -> Result<u32, HilError> {
            file.symbols()
                .find(|s| s.name() == Ok(name))
                .and_then(|s| u32::try_from(s.address()).ok())
                .ok_or_else(|| {
                    HilError::Io(format!(
                        "{} has no symbol {name} (not the controller's production image?)",
                        image.display()
                    ))
                })
        };
        let layout = RamLayout {
            statics_start: symbol("__sdata")?,
            stack_limit: symbol("__sheap")?,
            stack_top: symbol("_stack_start")?,
            busiest_period_counts: symbol("BUSIEST_PERIOD_COUNTS")?,
        };
        if layout.statics_start > layout.stack_limit || layout.stack_limit >= layout.stack_top {
            return Err(HilError::Io(format!(
                "{} has no room for a stack: statics from {:#x} to {:#x}, stack top {:#x}",
                image.display(),
                layout.statics_start,
                layout.stack_limit,
                layout.stack_top
            )));
        }
        Ok(layout)
    }

    /// Bytes between the statics' end and the stack's top: what is painted.
    pub fn free_bytes(&self) -> u32 {
        self.stack_top - self.stack_limit
    }

    /// Writes the paint for the free RAM into a file in `dir`, for QEMU's loader device.
    pub fn write_paint(&self, dir: &Path) -> Result<PathBuf, HilError> {
        let path = dir.join("stack-paint.bin");
        let paint: Vec<u8> =
            std::iter::repeat_n(PAINT.to_le_bytes(), (self.free_bytes() / 4) as usize)
                .flatten()
                .collect();
        std::fs::write(&path, paint)
            .map_err(|e| HilError::Io(format!("writing {}: {e}", path.display())))?;
        Ok(path)
    }

    /// The deepest the stack reached, from the free RAM saved after a run (`dump` starts at
    /// [`RamLayout::stack_limit`]): from the top down to the lowest word no longer painted.
    pub fn peak_stack_bytes(&self, dump: &[u8]) -> u32 {
        let painted_words = dump
            .chunks_exact(4)
            .take_while(|w| *w == PAINT.to_le_bytes())
            .count() as u32;
        self.free_bytes().saturating_sub(4 * painted_words)
    }
}

/// Instructions per SysTick count under QEMU's `-icount shift=0` (1 ns per instruction) on
/// the machine's 25 MHz clock.
pub const INSTRUCTIONS_PER_SYSTICK_COUNT: u64 = 40;

/// The firmware's RAM in use after a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RamUse {
    /// `.data`, `.bss` and `.uninit`.
    pub statics_bytes: u32,
    /// The stack at its deepest (painted).
    pub peak_stack_bytes: u32,
}

impl RamUse {
    /// Everything: what the budget's RAM (128 KiB) must hold.
    pub fn total_bytes(&self) -> u32 {
        self.statics_bytes + self.peak_stack_bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout() -> RamLayout {
        RamLayout {
            statics_start: 0x2000_0000,
            stack_limit: 0x2000_0100,
            stack_top: 0x2000_0200,
            busiest_period_counts: 0x2000_0000,
        }
    }

    #[test]
    fn the_peak_is_measured_from_the_lowest_word_written() {
        let layout = layout();
        let mut dump: Vec<u8> = std::iter::repeat_n(PAINT.to_le_bytes(), 64)
            .flatten()
            .collect();
        // The deepest frame wrote word 40; words above it that kept the paint still count.
        dump[160..164].copy_from_slice(&[0; 4]);
        dump[200..204].copy_from_slice(&PAINT.to_le_bytes());
        assert_eq!(layout.peak_stack_bytes(&dump), 256 - 160);
        let untouched: Vec<u8> = std::iter::repeat_n(PAINT.to_le_bytes(), 64)
            .flatten()
            .collect();
        assert_eq!(layout.peak_stack_bytes(&untouched), 0);
        assert_eq!(layout.peak_stack_bytes(&[0; 256]), 256);
    }

    #[test]
    fn paint_covers_the_free_ram_exactly() {
        let dir = std::env::temp_dir().join(format!("wheelleg-paint-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = layout().write_paint(&dir).unwrap();
        let paint = std::fs::read(&path).unwrap();
        assert_eq!(paint.len(), 256);
        assert_eq!(layout().peak_stack_bytes(&paint), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_that_is_no_image_is_named() {
        let dir = std::env::temp_dir().join(format!("wheelleg-noelf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("not-an-elf");
        std::fs::write(&path, b"hello").unwrap();
        let error = RamLayout::of_image(&path).unwrap_err().to_string();
        assert!(error.contains("no ELF image"), "{error}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
