//! `wheelleg inspect FILE`: what a weights file holds, checked exactly as the robot's runtime
//! checks it (same loader), so a file that inspects cleanly is a file the robot will load.

use super::CliResult;
use std::path::PathBuf;
use wheelleg_runtime::can::Axis;
use wheelleg_runtime::model::format::ROBOT_RECORD_VERSION;
use wheelleg_runtime::model::load::Model;

/// Arguments of `inspect`.
#[derive(clap::Args)]
pub struct Args {
    /// Weights file (.wlw).
    file: PathBuf,
}

/// Runs `inspect`.
pub fn run(args: Args) -> CliResult {
    let bytes = std::fs::read(&args.file).map_err(|e| format!("{}: {e}", args.file.display()))?;
    let model = Model::parse(&bytes).map_err(|e| format!("{}: {e}", args.file.display()))?;
    outln!(
        "{}: {} bytes, format version {}, checksum and structure valid",
        args.file.display(),
        bytes.len(),
        model.version
    );
    let trained = &model.trained_for;
    let g = &trained.robot.geometry;
    outln!(
        "robot     '{}'{}: thigh {} m, shank {} m, hips at x {} m, y {} m, wheels {} m{}; CAN nodes {}",
        trained.name,
        if model.version < ROBOT_RECORD_VERSION {
            " (files before format version 3 were all trained for the shipped robot)"
        } else {
            ""
        },
        g.thigh_m,
        g.shank_m,
        g.hip_x_m,
        g.hip_y_m,
        g.wheel_radius_m,
        if g.wheel_offset_m != 0.0 {
            format!(" {} m out from their mounts", g.wheel_offset_m)
        } else {
            String::new()
        },
        Axis::ALL
            .iter()
            .map(|&axis| trained.robot.can.node_id(axis).get().to_string())
            .collect::<Vec<_>>()
            .join(" ")
    );
    let a = &trained.robot.actions;
    outln!(
        "lattice   move {} m, yaw {} deg, clearance {} m, track {} m per step",
        a.move_step_m,
        a.yaw_step_deg,
        a.clearance_step_m,
        a.track_step_m
    );
    let input = &model.input;
    outln!(
        "input     height map {} x {}, {:.3} mm per step, zero point {}",
        input.rows,
        input.cols,
        input.height.scale_m * 1000.0,
        input.height.zero_point
    );
    // A version 2 state feature is int16 with zero point 256 x the stored one (docs/model.md).
    let state_zero_scale = if model.state_bits() == 16 { 256 } else { 1 };
    for (i, s) in model.state.iter().enumerate() {
        outln!(
            "state[{i}]  int{} {:.4} mm per step, zero point {}",
            model.state_bits(),
            s.scale_m * 1000.0,
            i32::from(s.zero_point) * state_zero_scale
        );
    }
    for (i, conv) in model.convs.iter().enumerate() {
        let r = &conv.record;
        outln!(
            "conv{i}     {}x{}x{} -> {}x{}x{}  kernel {} stride {} padding {}{}  out scale {:.5} zp {}",
            conv.in_rows,
            conv.in_cols,
            conv.in_channels,
            conv.out_rows,
            conv.out_cols,
            r.out_channels,
            r.kernel,
            r.stride,
            r.padding,
            if r.relu { " relu" } else { "" },
            r.output.scale,
            r.output.zero_point
        );
    }
    outln!(
        "flatten   {} x {} x {} features (CHW) + {} state",
        model.feature_channels,
        model.feature_rows,
        model.feature_cols,
        model.state.len()
    );
    let dense = |name: String, linear: &wheelleg_runtime::model::load::Linear<'_>| {
        outln!(
            "{name:<9} {} -> {}{}",
            linear.row_len,
            linear.rows,
            if linear.relu { " relu" } else { "" }
        );
    };
    for (i, d) in model.hidden.iter().enumerate() {
        dense(format!("dense{i}"), &d.linear);
    }
    dense("actions".into(), &model.action_head.linear);
    outln!(
        "          logits int{}, {} per step{}",
        model.logit_bits(),
        model.action_head.record.output.scale,
        if model.logit_bits() == 8 {
            format!(
                ", zero point {}",
                model.action_head.record.output.zero_point
            )
        } else {
            String::new()
        }
    );
    match &model.value_head {
        Some(v) => dense("value".into(), &v.linear),
        None => outln!("value     (not stored)"),
    }
    outln!(
        "totals    {} parameters, {} multiply-accumulates per decision, {} bytes of tensors",
        model.parameter_count(),
        model.macs(),
        model.tensor_bytes()
    );
    outln!(
        "buffers   activations {} x int8, widened row {} x i16",
        model.requirements.activation_elements,
        model.requirements.row_elements
    );
    Ok(())
}
