//! ODrive's enumerations as CANSimple carries them: axis states, control and input modes, and
//! the axis error bits this project uses.

/// ODrive axis states (`AXIS_STATE_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum AxisState {
    /// Not set.
    Undefined = 0,
    /// Motor off.
    Idle = 1,
    /// Startup sequence running.
    StartupSequence = 2,
    /// Full calibration running.
    FullCalibrationSequence = 3,
    /// Motor calibration running.
    MotorCalibration = 4,
    /// Encoder index search running.
    EncoderIndexSearch = 6,
    /// Encoder offset calibration running.
    EncoderOffsetCalibration = 7,
    /// Motor on, controller running.
    ClosedLoopControl = 8,
    /// Lockin spin.
    LockinSpin = 9,
    /// Encoder direction search.
    EncoderDirFind = 10,
    /// Homing.
    Homing = 11,
    /// Hall polarity calibration.
    EncoderHallPolarityCalibration = 12,
    /// Hall phase calibration.
    EncoderHallPhaseCalibration = 13,
}

impl AxisState {
    /// The state with this value; `None` for values ODrive does not define.
    pub const fn from_raw(raw: u32) -> Option<AxisState> {
        Some(match raw {
            0 => AxisState::Undefined,
            1 => AxisState::Idle,
            2 => AxisState::StartupSequence,
            3 => AxisState::FullCalibrationSequence,
            4 => AxisState::MotorCalibration,
            6 => AxisState::EncoderIndexSearch,
            7 => AxisState::EncoderOffsetCalibration,
            8 => AxisState::ClosedLoopControl,
            9 => AxisState::LockinSpin,
            10 => AxisState::EncoderDirFind,
            11 => AxisState::Homing,
            12 => AxisState::EncoderHallPolarityCalibration,
            13 => AxisState::EncoderHallPhaseCalibration,
            _ => return None,
        })
    }
}

/// ODrive control modes (`CONTROL_MODE_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ControlMode {
    /// Voltage control.
    Voltage = 0,
    /// Torque control.
    Torque = 1,
    /// Velocity control: used for the wheels.
    Velocity = 2,
    /// Position control: used for the leg joints.
    Position = 3,
}

impl ControlMode {
    /// The mode with this value.
    pub const fn from_raw(raw: u32) -> Option<ControlMode> {
        Some(match raw {
            0 => ControlMode::Voltage,
            1 => ControlMode::Torque,
            2 => ControlMode::Velocity,
            3 => ControlMode::Position,
            _ => return None,
        })
    }
}

/// ODrive input modes (`INPUT_MODE_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum InputMode {
    /// Inputs ignored.
    Inactive = 0,
    /// Setpoints used as sent: the runtime already smooths them, so this is what it uses.
    Passthrough = 1,
    /// Velocity ramp.
    VelRamp = 2,
    /// Second-order position filter.
    PosFilter = 3,
    /// Mixed channels.
    MixChannels = 4,
    /// Trapezoidal trajectory.
    TrapTraj = 5,
    /// Torque ramp.
    TorqueRamp = 6,
    /// Mirror another axis.
    Mirror = 7,
    /// Tuning.
    Tuning = 8,
}

impl InputMode {
    /// The mode with this value.
    pub const fn from_raw(raw: u32) -> Option<InputMode> {
        Some(match raw {
            0 => InputMode::Inactive,
            1 => InputMode::Passthrough,
            2 => InputMode::VelRamp,
            3 => InputMode::PosFilter,
            4 => InputMode::MixChannels,
            5 => InputMode::TrapTraj,
            6 => InputMode::TorqueRamp,
            7 => InputMode::Mirror,
            8 => InputMode::Tuning,
            _ => return None,
        })
    }
}

/// ODrive axis error bits (`AXIS_ERROR_*`, firmware 0.5.x) that this project uses.
pub mod axis_error {
    /// A state was requested that the axis cannot enter.
    pub const INVALID_STATE: u32 = 0x0000_0001;
    /// The controller failed: the simulated axis raises it for out-of-range setpoints.
    pub const CONTROLLER_FAILED: u32 = 0x0000_0200;
    /// No command arrived within the watchdog timeout.
    pub const WATCHDOG_TIMER_EXPIRED: u32 = 0x0000_0800;
    /// An Estop message was received.
    pub const ESTOP_REQUESTED: u32 = 0x0000_4000;
}
