//! Runs a few steps of the closed loop on the in-process bus and writes the bus traffic as a
//! `candump -L` log: `cargo run --release -p wheelleg-firmware-sim --example closed_loop_log --
//! out.log`. tools/check_dbc.py decodes such a log with ODrive's DBC.

use std::io::BufWriter;
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::{Rig, RigConfig};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::bus_load::{bus_load, Traffic};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::{Robot, WHEELLEG};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "closed_loop.log".to_owned());
    let start = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut rig = Rig::in_process(&Robot::WHEELLEG, RigConfig::default(), start)?;
    let file = BufWriter::new(std::fs::File::create(&path)?);
    rig.log_to(CandumpWriter::new(Box::new(file), "can0", DEFAULT_EPOCH_US));
    rig.start_up()?;
    let steps = [
        Action {
            move_x: Step::Plus,
            ..Action::IDLE
        },
        Action {
            move_y: Step::Plus,
            yaw: Step::Minus,
            track: Step::Plus,
            ..Action::IDLE
        },
        Action {
            clearance: Step::Plus,
            ..Action::IDLE
        },
    ];
    for action in steps {
        let r = rig.step(action)?;
        println!(
            "{action:?}: position error {:.2} mm, yaw error {:.3} deg",
            1e3 * r.position_error_m(),
            r.yaw_error_rad().to_degrees()
        );
    }
    // End with the safety messages too, so the log exercises every command the robot sends.
    rig.estop()?;
    rig.recover()?;
    rig.take_log()?;
    let load = bus_load(&Traffic::default(), 1e6);
    println!(
        "wrote {path}; bus load at 1 Mbit/s: {:.1} % nominal, {:.1} % worst case",
        100.0 * load.nominal_fraction,
        100.0 * load.worst_fraction
    );
    Ok(())
}
