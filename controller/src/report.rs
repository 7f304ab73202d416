//! The link's reports of the control loop's state, as every controller image sends them: a safe
//! stop with its reason, and the end of a step with the odometry and the measured legs.

use embedded_can::Frame;

use crate::control::{Control, ControlError, Stop, StopReason};
use crate::wire::{stop_reason, FromController};

/// The report of a stopped controller.
pub fn stop_report(stop: Stop) -> FromController {
    let (reason, axes) = match stop.reason {
        StopReason::Silent(axes) => (stop_reason::SILENT_AXES, axes.0),
        StopReason::AxisError(axes) => (stop_reason::AXIS_ERRORS, axes.0),
        StopReason::CanLink => (stop_reason::CAN_LINK, 0),
        StopReason::ObservationStalled => (stop_reason::OBSERVATION_STALLED, 0),
        StopReason::ObservationCorrupt => (stop_reason::OBSERVATION_CORRUPT, 0),
        StopReason::StartupFailed => (stop_reason::STARTUP_FAILED, 0),
        StopReason::Control => (stop_reason::CONTROL, 0),
        StopReason::Estop => (stop_reason::ESTOP, 0),
    };
    FromController::Stopped {
        reason,
        axes,
        tick: stop.tick,
    }
}

/// The report after a step (or a retreat) that ended with `driven`: its end, or the safe stop
/// it ended in. Legs out of reach moved nothing (nothing was sent, as on the host); any other
/// error puts the robot in safe stop.
pub fn step_report<F: Frame>(
    control: &mut Control<F>,
    driven: Result<(), ControlError>,
) -> FromController {
    let moved = match driven {
        Ok(()) => true,
        Err(ControlError::Motion(_)) => false,
        Err(_) => {
            control.stop(StopReason::Control);
            true
        }
    };
    if let Some(stop) = control.stop_state() {
        return stop_report(stop);
    }
    let pose = control.odometry().pose;
    let legs = control.measured_legs().unwrap_or(control.legs());
    FromController::StepDone {
        moved,
        pose: [
            pose.translation.x,
            pose.translation.y,
            pose.rotation.angle(),
        ],
        legs_m: [legs.clearance_m, legs.track_m],
        tick: control.ticks(),
    }
}
