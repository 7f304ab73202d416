//! The motors of the firmware in the loop: the 16 simulated ODrive axes on an in-process bus,
//! behind an SLCAN adapter that the firmware drives over its CAN UART.
//!
//! Two clocks ([`PlantClock`]). In **lockstep** time is the firmware's: the firmware starts
//! every control period with the adapter's status poll (`F`), and the adapter answers it only
//! after it has run the motors for the period that ended (ten 1 ms physics steps, as the host's
//! rig does) and sent the firmware every frame the axes put on the bus in it. So the motors and
//! the firmware move in lockstep, one period per poll, however fast QEMU runs, and the frames
//! are those of the host's closed loop: the firmware's frames go on the bus when their lines
//! arrive, in the period they were sent.
//!
//! On the **emulated** clock time is QEMU's: the firmware built with its `emulated-clock`
//! feature stamps each period's frames with a hardware timer's count (`@` and 8 hex digits of
//! its 25 MHz ticks), a clock that runs on QEMU's instruction count (`-icount`), whatever the
//! firmware is doing. The motors and their watchdogs advance to each stamp before they take
//! the frames after it, so a period the firmware sends late, or not at all, costs the motors
//! time as on a board; each stamp is checked against its period's due time ([`PeriodTiming`]).
//!
//! Faults are injected here, at a chosen period: an axis goes silent, the link drops frame
//! lines towards the firmware, or the adapter stops answering altogether.

use std::io::Write;

use nalgebra::Isometry2;
use wheelleg_firmware_sim::bus::{InProcessBus, Port, Transport};
use wheelleg_firmware_sim::candump::CandumpWriter;
use wheelleg_firmware_sim::firmware::Firmware;
use wheelleg_firmware_sim::rig::{MeasuredBusLoad, TrafficCounts};
use wheelleg_firmware_sim::slcan::SlcanAdapter;
use wheelleg_runtime::base::{MecanumBase, Odometry, WheelSpeeds};
use wheelleg_runtime::can::bus_load::frame_bits;
use wheelleg_runtime::can::node_map::{Axis, NodeMap};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::robot::RobotGeometry;

/// The control period the firmware polls once per.
pub const PERIOD_US: u64 = 10_000;
/// The motors' physics step (the rig's).
pub const PHYSICS_US: u64 = 1_000;
/// The axes' watchdog, configured as the host's rig configures it: the firmware relies on it to
/// idle the motors when its frames stop reaching them (a dead CAN link).
pub const WATCHDOG_TIMEOUT_US: u64 = 100_000;

/// What the motors' time follows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PlantClock {
    /// One control period per status poll of the firmware.
    #[default]
    Lockstep,
    /// The firmware's stamps of QEMU's clock (an image built with `emulated-clock`).
    Emulated,
}

/// A period whose setpoints reach the bus later than this after its due time is late.
pub const LATE_AFTER_US: u64 = 1_000;

/// The firmware's control periods on the emulated clock: each stamped period's setpoints
/// against its due time (the first stamp's time plus whole periods).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PeriodTiming {
    /// Periods stamped.
    pub periods: u64,
    /// Periods due whose setpoints came more than [`LATE_AFTER_US`] late, or never.
    pub late: u64,
    /// The latest a period's setpoints came, after its due time, in microseconds.
    pub worst_lateness_us: u64,
}

/// The robot while held (the firmware between two steps, deciding): how far the true legs
/// moved from where the watch began, and how fast the wheels turned at most.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HoldWatch {
    /// Legs (clearance and track, by forward kinematics of the true joints) where it began.
    pub start: Option<LegConfig>,
    /// The largest change of clearance or track since, in metres.
    pub max_leg_change_m: f32,
    /// The largest sum of the wheels' absolute speeds, turns/s.
    pub max_wheel_speed_sum: f32,
    /// Physics steps watched (1 ms each).
    pub steps: u64,
}

/// A fault to inject from a given control period on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PlantFault {
    /// The axis stops transmitting (it still obeys commands).
    SilentAxis(Axis),
    /// Each frame line towards the firmware is lost with this probability (seeded).
    DropFrames(f64),
    /// The adapter stops answering: nothing more reaches the firmware, nor the bus.
    DeadLink,
}

/// Where the robot really is, from the simulated motors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// Pose relative to the start, integrated from the motors' true wheel speeds.
    pub pose: Isometry2<f32>,
    /// Legs by forward kinematics of the true joint positions (mean of the four legs).
    pub legs: LegConfig,
    /// Sum of the wheel motors' absolute speeds, turns/s.
    pub wheel_speed_sum: f32,
}

/// The adapter, the bus and the axes.
pub struct Plant {
    geometry: RobotGeometry,
    map: NodeMap,
    axes: Firmware,
    adapter: Port,
    axes_port: Port,
    slcan: SlcanAdapter,
    line: Vec<u8>,
    /// Periods polled so far (the firmware's control periods since its first).
    polls: u64,
    now_us: u64,
    log: Option<CandumpWriter<Box<dyn Write + Send>>>,
    traffic: TrafficCounts,
    delivered: u64,
    truth: Odometry,
    faults: Vec<(u64, PlantFault)>,
    drop_probability: f64,
    rng: u64,
    dead: bool,
    /// The first period of each fault injected, as it took effect.
    injected: Vec<(u64, PlantFault)>,
    clock: PlantClock,
    /// The emulated clock's stamps so far, unwrapped: the last one's raw count and the total.
    stamp: Option<(u32, u64)>,
    /// The first stamp's time (the motors' clock starts there), the first setpoints' time on
    /// the motors' clock, and the last stamped period's index from it.
    first_stamp_us: Option<u64>,
    first_setpoints_us: Option<u64>,
    last_period: Option<u64>,
    timing: PeriodTiming,
    watch: Option<HoldWatch>,
}

impl Plant {
    /// The axes of a robot of `geometry` on the nodes of `map`, with the legs at `start`,
    /// wheels at rest, all idle.
    pub fn new(
        geometry: &RobotGeometry,
        map: &NodeMap,
        start: LegConfig,
    ) -> Result<Plant, IkError> {
        let map = *map;
        let bus = InProcessBus::default();
        let mut axes = Firmware::for_robot(geometry, &map, start)?;
        axes.set_watchdog_timeout_us(WATCHDOG_TIMEOUT_US);
        Ok(Plant {
            geometry: *geometry,
            map,
            axes,
            adapter: bus.port(),
            axes_port: bus.port(),
            slcan: SlcanAdapter::new(),
            line: Vec::new(),
            polls: 0,
            now_us: 0,
            log: None,
            traffic: TrafficCounts::default(),
            delivered: 0,
            truth: Odometry::default(),
            faults: Vec::new(),
            drop_probability: 0.0,
            rng: 0x5EED,
            dead: false,
            injected: Vec::new(),
            clock: PlantClock::Lockstep,
            stamp: None,
            first_stamp_us: None,
            first_setpoints_us: None,
            last_period: None,
            timing: PeriodTiming::default(),
            watch: None,
        })
    }

    /// Runs the motors on `clock` from now on (before the firmware starts).
    pub fn set_clock(&mut self, clock: PlantClock) {
        self.clock = clock;
    }

    /// The firmware's periods on the emulated clock so far.
    pub fn timing(&self) -> PeriodTiming {
        self.timing
    }

    /// Watchdog expiries of all axes so far.
    pub fn watchdog_trips(&self) -> u32 {
        self.axes
            .axes()
            .iter()
            .map(|a| a.stats().watchdog_trips)
            .sum()
    }

    /// Begins watching the robot held (see [`HoldWatch`]); [`Self::end_watch`] ends it.
    pub fn begin_watch(&mut self) {
        self.watch = Some(HoldWatch {
            start: self.true_legs(),
            ..HoldWatch::default()
        });
    }

    /// Ends the watch begun last, with what it saw.
    pub fn end_watch(&mut self) -> Option<HoldWatch> {
        self.watch.take()
    }

    /// Logs every frame on the bus in `candump -L` format from now on.
    pub fn log_to(&mut self, writer: CandumpWriter<Box<dyn Write + Send>>) {
        self.log = Some(writer);
    }

    /// Stops logging; returns the flushed writer.
    pub fn take_log(&mut self) -> std::io::Result<Option<Box<dyn Write + Send>>> {
        self.log.take().map(CandumpWriter::finish).transpose()
    }

    /// Injects `fault` when the firmware polls period `at_period` (0 is its first).
    pub fn schedule(&mut self, at_period: u64, fault: PlantFault) {
        self.faults.push((at_period, fault));
    }

    /// The faults injected so far, with the period each took effect in.
    pub fn injected(&self) -> &[(u64, PlantFault)] {
        &self.injected
    }

    /// Control periods the firmware has polled.
    pub fn polls(&self) -> u64 {
        self.polls
    }

    /// Simulated time: the periods polled.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// Frames on the bus so far (both ways).
    pub fn traffic(&self) -> TrafficCounts {
        self.traffic
    }

    /// Frames handed to the firmware.
    pub fn delivered(&self) -> u64 {
        self.delivered
    }

    /// The bus load so far at `bitrate_bps`.
    pub fn bus_load(&self, bitrate_bps: f64) -> Option<MeasuredBusLoad> {
        if self.now_us == 0 || bitrate_bps <= 0.0 {
            return None;
        }
        let elapsed_s = self.now_us as f64 * 1e-6;
        Some(MeasuredBusLoad {
            frames_per_s: self.traffic.frames as f64 / elapsed_s,
            nominal: self.traffic.bits_nominal as f64 / (bitrate_bps * elapsed_s),
            worst_case: self.traffic.bits_worst_case as f64 / (bitrate_bps * elapsed_s),
        })
    }

    /// The simulated axes.
    pub fn axes(&self) -> &Firmware {
        &self.axes
    }

    /// Where the robot really is.
    pub fn truth(&self) -> Truth {
        Truth {
            pose: self.truth.pose,
            legs: self.true_legs().unwrap_or(LegConfig {
                clearance_m: 0.0,
                track_m: 0.0,
            }),
            wheel_speed_sum: wheelleg_firmware_sim::rig::true_wheel_speed_sum(&self.axes),
        }
    }

    /// Takes bytes the firmware sent on its CAN UART; returns what the adapter answers (on the
    /// emulated clock, with a zero byte after each period's stamp: see [`PlantClock`]).
    pub fn feed(&mut self, bytes: &[u8]) -> std::io::Result<Vec<u8>> {
        let mut out = Vec::new();
        for &byte in bytes {
            if self.dead && self.clock == PlantClock::Lockstep {
                continue;
            }
            self.line.push(byte);
            if byte != b'\r' {
                continue;
            }
            let line = std::mem::take(&mut self.line);
            match line.first() {
                Some(b'@') => {
                    let at_us = self.stamped(&line)?;
                    self.advance_to(at_us)?;
                    if !self.dead {
                        self.deliver()?;
                        self.drain_output(&mut out);
                    }
                    out.push(0);
                    continue;
                }
                Some(b'!') => {
                    let at_us = self.stamped(&line)?;
                    self.check_lateness(at_us);
                    self.advance_to(at_us)?;
                    continue;
                }
                _ => {}
            }
            if line.as_slice() == b"F\r" {
                self.period()?;
            }
            if self.dead {
                continue;
            }
            self.slcan.receive_bytes(&line);
            while let Some(frame) = self.slcan.next_frame() {
                self.count(&frame)?;
                self.adapter
                    .send(&frame, self.now_us)
                    .map_err(std::io::Error::other)?;
            }
            self.drain_output(&mut out);
        }
        Ok(out)
    }

    /// Moves the adapter's answers so far into `out`.
    fn drain_output(&mut self, out: &mut Vec<u8>) {
        let pending = self.slcan.pending_output();
        out.extend_from_slice(pending);
        let len = pending.len();
        self.slcan.consume_output(len);
    }

    fn count(&mut self, frame: &CanFrame) -> std::io::Result<()> {
        use embedded_can::Frame;
        if let Some(log) = &mut self.log {
            log.log(self.now_us, frame)?;
        }
        let data_len = if frame.is_remote_frame() {
            0
        } else {
            frame.data().len() as u8
        };
        let bits = frame_bits(data_len);
        self.traffic.frames += 1;
        self.traffic.bits_nominal += u64::from(bits.nominal);
        self.traffic.bits_worst_case += u64::from(bits.worst_case);
        Ok(())
    }

    /// A poll: the motors run for the period that ended, then its frames go to the firmware.
    fn period(&mut self) -> std::io::Result<()> {
        let period = self.polls;
        self.polls += 1;
        let (due, later): (Vec<_>, Vec<_>) =
            self.faults.drain(..).partition(|(at, _)| *at <= period);
        self.faults = later;
        for (_, fault) in due {
            self.injected.push((period, fault));
            match fault {
                PlantFault::SilentAxis(axis) => {
                    if let Some(motor) = self.axes.axis_mut(axis) {
                        motor.set_silent(true);
                    }
                }
                PlantFault::DropFrames(p) => self.drop_probability = p,
                PlantFault::DeadLink => self.dead = true,
            }
        }
        // On the emulated clock the motors follow the stamps, and the bus's frames go to the
        // firmware at each period's start stamp.
        if self.clock == PlantClock::Emulated || period == 0 {
            return Ok(());
        }
        self.advance_to(self.now_us + PERIOD_US)?;
        if self.dead {
            return Ok(());
        }
        self.deliver()
    }

    /// The frames the axes put on the bus so far, to the firmware (less those a fault drops).
    fn deliver(&mut self) -> std::io::Result<()> {
        while let Some(frame) = self
            .adapter
            .recv(self.now_us)
            .map_err(std::io::Error::other)?
        {
            self.count(&frame)?;
            if self.drop_probability > 0.0 && self.next_uniform() < self.drop_probability {
                continue;
            }
            if self.slcan.frame_to_client(&frame, self.now_us) {
                self.delivered += 1;
            }
        }
        Ok(())
    }

    /// Runs the motors in whole physics steps up to `end_us`.
    fn advance_to(&mut self, end_us: u64) -> std::io::Result<()> {
        let dt_s = PHYSICS_US as f32 * 1e-6;
        while self.now_us + PHYSICS_US <= end_us {
            self.now_us += PHYSICS_US;
            self.axes
                .run(&mut self.axes_port, self.now_us, dt_s)
                .map_err(std::io::Error::other)?;
            let legs = self.true_legs();
            if let (Some(legs), Some(wheels)) = (legs, self.true_wheel_speeds()) {
                if let Ok(base) = MecanumBase::at(&self.geometry, legs) {
                    let _ = self.truth.integrate_wheels(&base, wheels, dt_s);
                }
            }
            if let Some(watch) = self.watch.as_mut() {
                watch.steps += 1;
                if let (Some(start), Some(legs)) = (watch.start, legs) {
                    let change_m = (legs.clearance_m - start.clearance_m)
                        .abs()
                        .max((legs.track_m - start.track_m).abs());
                    watch.max_leg_change_m = watch.max_leg_change_m.max(change_m);
                }
                let wheels = wheelleg_firmware_sim::rig::true_wheel_speed_sum(&self.axes);
                watch.max_wheel_speed_sum = watch.max_wheel_speed_sum.max(wheels);
            }
        }
        Ok(())
    }

    /// The time of a stamp line of the emulated clock, on the motors' clock (which starts with
    /// the firmware's first stamp: until then the axes sat idle, and a real bus's frames of
    /// that time would be long gone).
    fn stamped(&mut self, line: &[u8]) -> std::io::Result<u64> {
        let counts = std::str::from_utf8(line.get(1..9).unwrap_or(&[]))
            .ok()
            .and_then(|hex| u32::from_str_radix(hex, 16).ok())
            .ok_or_else(|| {
                std::io::Error::other(format!(
                    "a stamp line that is no stamp: {:?}",
                    String::from_utf8_lossy(line)
                ))
            })?;
        if self.clock != PlantClock::Emulated {
            return Err(std::io::Error::other(
                "a stamped period in lockstep: the image is built for the emulated clock",
            ));
        }
        // Timer 0 counts 25 MHz ticks and wraps after 172 s.
        let total = match self.stamp {
            Some((last, total)) => total + u64::from(counts.wrapping_sub(last)),
            None => u64::from(counts),
        };
        self.stamp = Some((counts, total));
        let stamp_us = total / 25;
        let first_us = *self.first_stamp_us.get_or_insert(stamp_us);
        Ok(stamp_us - first_us)
    }

    /// Checks the setpoints stamped at `at_us` against their period's due time. The first
    /// period's setpoints are the reference (a period's come a little after its interrupt),
    /// and a stamp is its period's when within half a period of its due time: one more than
    /// half a period late reads as the next period's, the one between counted as skipped.
    fn check_lateness(&mut self, at_us: u64) {
        let first_us = *self.first_setpoints_us.get_or_insert(at_us);
        let since_us = at_us.saturating_sub(first_us);
        let period = (since_us + PERIOD_US / 2) / PERIOD_US;
        let lateness_us = since_us.saturating_sub(period * PERIOD_US);
        // Periods between the last stamped one and this one sent no setpoints at all.
        let skipped = self
            .last_period
            .map_or(0, |last| period.saturating_sub(last + 1));
        if skipped > 0 {
            self.timing.late += skipped;
            self.timing.worst_lateness_us = self
                .timing
                .worst_lateness_us
                .max(lateness_us + skipped * PERIOD_US);
        }
        if self.last_period != Some(period) {
            self.timing.periods += 1;
            if lateness_us > LATE_AFTER_US {
                self.timing.late += 1;
            }
            self.timing.worst_lateness_us = self.timing.worst_lateness_us.max(lateness_us);
        }
        self.last_period = Some(period);
    }

    /// SplitMix64, seeded: the dropped lines are the same every run.
    fn next_uniform(&mut self) -> f64 {
        self.rng = self.rng.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn true_legs(&self) -> Option<LegConfig> {
        self.axes.true_legs(&self.map, &self.geometry)
    }

    fn true_wheel_speeds(&self) -> Option<WheelSpeeds> {
        self.axes.true_wheel_speeds(&self.map)
    }
}
