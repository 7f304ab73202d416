//! How much of the bus a control cycle uses, from the bit counts of classic CAN frames.
//!
//! A standard-id (11-bit) data frame with `n` payload bytes is, on the wire:
//!
//! ```text
//! SOF 1 + id 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15   = 34 + 8n  (stuffed)
//! CRC delimiter 1 + ACK slot 1 + ACK delimiter 1 + EOF 7            = 10       (not stuffed)
//! intermission 3                                                    = 3
//! ```
//!
//! so `47 + 8n` bits nominally. Bit stuffing inserts a complementary bit after five equal bits
//! in the stuffed region; the worst case is one stuff bit per four bits after the first, i.e.
//! `floor((34 + 8n - 1) / 4)` extra bits: 24 for a full 8-byte frame (135 bits instead of 111).

/// Bits of a standard-id frame on the wire, including the 3-bit intermission.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameBits {
    /// Without stuff bits.
    pub nominal: u32,
    /// With the largest possible number of stuff bits.
    pub worst_case: u32,
}

/// Bit count of a standard-id data frame with `data_len` payload bytes (clamped to 8).
pub const fn frame_bits(data_len: u8) -> FrameBits {
    let n = if data_len > 8 { 8 } else { data_len } as u32;
    let stuffed_region = 34 + 8 * n;
    let nominal = stuffed_region + 10 + 3;
    FrameBits {
        nominal,
        worst_case: nominal + (stuffed_region - 1) / 4,
    }
}

/// The periodic traffic of the robot: 16 axes, each receiving one 8-byte setpoint per control
/// tick and sending 8-byte encoder estimates and heartbeats at their own rates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Traffic {
    /// Control ticks per second (one Set_Input_Pos or Set_Input_Vel per axis each).
    pub control_rate_hz: f32,
    /// Encoder estimates per second per axis.
    pub estimate_rate_hz: f32,
    /// Heartbeats per second per axis.
    pub heartbeat_rate_hz: f32,
    /// Number of axes.
    pub axes: u32,
}

impl Default for Traffic {
    /// The project's defaults: 100 Hz control, estimates at the control rate, heartbeats at
    /// 10 Hz, 16 axes.
    fn default() -> Self {
        Traffic {
            control_rate_hz: 100.0,
            estimate_rate_hz: 100.0,
            heartbeat_rate_hz: 10.0,
            axes: 16,
        }
    }
}

/// Bus usage of one control cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BusLoad {
    /// Frames per control cycle (fractional when a rate is below the control rate).
    pub frames_per_cycle: f32,
    /// Bits per control cycle without stuffing.
    pub nominal_bits_per_cycle: f32,
    /// Bits per control cycle with worst-case stuffing.
    pub worst_bits_per_cycle: f32,
    /// Fraction of the bus's capacity used, nominal.
    pub nominal_fraction: f32,
    /// Fraction of the bus's capacity used, worst case.
    pub worst_fraction: f32,
}

/// Bus load of `traffic` at `bitrate_bps` (1 Mbit/s for this robot).
pub fn bus_load(traffic: &Traffic, bitrate_bps: f32) -> BusLoad {
    let bits = frame_bits(8);
    let axes = traffic.axes as f32;
    let per_cycle = |rate_hz: f32| axes * rate_hz / traffic.control_rate_hz;
    let frames_per_cycle =
        axes + per_cycle(traffic.estimate_rate_hz) + per_cycle(traffic.heartbeat_rate_hz);
    let nominal_bits_per_cycle = frames_per_cycle * bits.nominal as f32;
    let worst_bits_per_cycle = frames_per_cycle * bits.worst_case as f32;
    let bits_per_cycle_available = bitrate_bps / traffic.control_rate_hz;
    BusLoad {
        frames_per_cycle,
        nominal_bits_per_cycle,
        worst_bits_per_cycle,
        nominal_fraction: nominal_bits_per_cycle / bits_per_cycle_available,
        worst_fraction: worst_bits_per_cycle / bits_per_cycle_available,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_bit_counts_match_the_can_standard() {
        assert_eq!(
            frame_bits(8),
            FrameBits {
                nominal: 111,
                worst_case: 135
            }
        );
        assert_eq!(
            frame_bits(0),
            FrameBits {
                nominal: 47,
                worst_case: 55
            }
        );
    }

    #[test]
    fn default_cycle_fits_a_1_mbit_bus_with_margin() {
        let load = bus_load(&Traffic::default(), 1_000_000.0);
        // 16 setpoints + 16 estimates + 1.6 heartbeats per 10 ms cycle.
        assert!((load.frames_per_cycle - 33.6).abs() < 1e-4);
        assert!((load.worst_bits_per_cycle - 33.6 * 135.0).abs() < 1e-2);
        assert!((load.worst_fraction - 0.4536).abs() < 1e-4);
        assert!((load.nominal_fraction - 0.37296).abs() < 1e-4);
    }
}
