//! The motors of the firmware in the loop: the 16 simulated ODrive axes on an in-process bus,
//! behind an SLCAN adapter that the firmware drives over its CAN UART.
//!
//! Time is the firmware's: the firmware starts every control period with the adapter's status
//! poll (`F`), and the adapter answers it only after it has run the motors for the period that
//! ended (ten 1 ms physics steps, as the host's rig does) and sent the firmware every frame the
//! axes put on the bus in it. So the motors and the firmware move in lockstep, one period per
//! poll, however fast QEMU runs, and the frames are those of the host's closed loop: the
//! firmware's frames go on the bus when their lines arrive, in the period they were sent.
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
}

impl Plant {
    /// The axes with the legs at `start`, wheels at rest, all idle.
    pub fn new(geometry: &RobotGeometry, start: LegConfig) -> Result<Plant, IkError> {
        let map = NodeMap::NOMINAL;
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
        })
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

    /// Takes bytes the firmware sent on its CAN UART; returns what the adapter answers.
    pub fn feed(&mut self, bytes: &[u8]) -> std::io::Result<Vec<u8>> {
        for &byte in bytes {
            if self.dead {
                continue;
            }
            self.line.push(byte);
            if byte != b'\r' {
                continue;
            }
            let line = std::mem::take(&mut self.line);
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
        }
        let out = self.slcan.pending_output().to_vec();
        self.slcan.consume_output(out.len());
        Ok(out)
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
        if period == 0 {
            return Ok(());
        }
        let dt_s = PHYSICS_US as f32 * 1e-6;
        let end_us = self.now_us + PERIOD_US;
        while self.now_us < end_us {
            self.now_us += PHYSICS_US;
            self.axes
                .run(&mut self.axes_port, self.now_us, dt_s)
                .map_err(std::io::Error::other)?;
            if let (Some(legs), Some(wheels)) = (self.true_legs(), self.true_wheel_speeds()) {
                if let Ok(base) = MecanumBase::at(&self.geometry, legs) {
                    let _ = self.truth.integrate_wheels(&base, wheels, dt_s);
                }
            }
        }
        if self.dead {
            return Ok(());
        }
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
