//! What the host reads from outside the firmware, through QEMU's monitor: its RAM in use (the
//! painted stack) and its busiest control period.

use super::*;

/// Instructions per SysTick count (25 MHz) on `clock`'s instruction clock ([`icount`]).
pub fn instructions_per_systick_count(clock: PlantClock) -> u64 {
    match clock {
        PlantClock::Lockstep => memory::INSTRUCTIONS_PER_SYSTICK_COUNT,
        PlantClock::Emulated => memory::INSTRUCTIONS_PER_SYSTICK_COUNT / 4,
    }
}

impl Hil {
    /// Reads the monitor's output up to its next prompt.
    pub(super) fn monitor_prompt(&mut self) -> Result<String, HilError> {
        let deadline = Instant::now() + ANSWER_TIMEOUT;
        let mut out = Vec::new();
        let mut buf = [0u8; 1024];
        while !out.ends_with(b"(qemu) ") {
            if Instant::now() > deadline {
                return Err(HilError::Protocol("QEMU's monitor did not answer".into()));
            }
            self.monitor
                .set_read_timeout(Some(Duration::from_secs(1)))
                .map_err(io("QEMU's monitor"))?;
            match self.monitor.read(&mut buf) {
                Ok(0) => return Err(HilError::Protocol("QEMU closed its monitor".into())),
                Ok(n) => out.extend_from_slice(&buf[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(io("reading QEMU's monitor")(e)),
            }
        }
        Ok(String::from_utf8_lossy(&out).into_owned())
    }

    /// The firmware's RAM in use so far: its statics, and its stack at the deepest, from the
    /// free RAM painted at the start and saved now by QEMU's monitor.
    pub fn ram_use(&mut self) -> Result<RamUse, HilError> {
        let bytes = self.save_ram(self.layout.stack_limit, self.layout.free_bytes())?;
        Ok(RamUse {
            statics_bytes: self.layout.stack_limit - self.layout.statics_start,
            peak_stack_bytes: self.layout.peak_stack_bytes(&bytes),
        })
    }

    /// The most instructions the firmware spent on one control period's work so far (its waits
    /// for the CAN adapter's bytes left out), read from its RAM by QEMU's monitor: the firmware
    /// keeps the figure in SysTick counts, each 40 instructions under `-icount shift=0`.
    pub fn busiest_period_instructions(&mut self) -> Result<u64, HilError> {
        let bytes = self.save_ram(self.layout.busiest_period_counts, 4)?;
        let counts = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
        Ok(u64::from(counts) * instructions_per_systick_count(self.clock))
    }

    /// `len` bytes of the firmware's RAM from `address`, saved by QEMU's monitor.
    pub(super) fn save_ram(&mut self, address: u32, len: u32) -> Result<Vec<u8>, HilError> {
        let dump = self.scratch.join("ram.bin");
        let _ = std::fs::remove_file(&dump);
        let command = format!("pmemsave {address:#x} {len} \"{}\"\n", dump.display());
        self.monitor
            .write_all(command.as_bytes())
            .map_err(io("writing to QEMU's monitor"))?;
        let answer = self.monitor_prompt()?;
        let bytes = std::fs::read(&dump).map_err(|e| {
            HilError::Protocol(format!(
                "QEMU's monitor saved no RAM ({e}); it answered: {}",
                answer.trim()
            ))
        })?;
        if bytes.len() != len as usize {
            return Err(HilError::Protocol(format!(
                "QEMU's monitor saved {} bytes of RAM, not {len}",
                bytes.len()
            )));
        }
        Ok(bytes)
    }
}
