//! A second robot, and one on another action lattice, through the whole host chain at smoke
//! size: its description checked, scenes generated and planned for it, a short training, the
//! export, the evaluation and the demo on the bus with its own node ids, and every file of one
//! robot refused for the other.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const STRIDER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/strider.toml");
const SMOKE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/configs/smoke.toml");

fn wheelleg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_wheelleg"))
        .args(args)
        .output()
        .expect("the wheelleg binary runs")
}

fn ok(args: &[&str]) -> String {
    let out = wheelleg(args);
    assert!(
        out.status.success(),
        "wheelleg {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn refused(args: &[&str]) -> String {
    let out = wheelleg(args);
    assert!(!out.status.success(), "wheelleg {args:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `eval` with `args` on one generated straight scene, refused; its error.
fn eval_refused(args: &[&str]) -> String {
    let mut all = vec!["eval"];
    all.extend_from_slice(args);
    all.extend_from_slice(&[
        "--generated",
        "1",
        "--kind",
        "straight",
        "--max-expansions",
        "0",
    ]);
    refused(&all)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-chain-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A refusal of a strider file for the shipped robot names both.
fn names_both_robots(err: &str) {
    assert!(
        err.contains("'strider'") && err.contains("'wheelleg'"),
        "{err}"
    );
}

fn s(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Scenes generated and planned for `robot`, a short training, the export, the evaluation and
/// the demo on the bus; every frame of the demo must go to nodes 21 to 36. The checkpoint and
/// the weights file, for the caller's refusals.
fn through_the_chain(robot: &str, dir: &Path) -> (PathBuf, PathBuf) {
    // Scenes built for it, each solved by the planner on its geometry and lattice.
    let scenes = dir.join("lift.json");
    ok(&[
        "generate",
        "--robot",
        robot,
        "--kind",
        "lift",
        "--count",
        "3",
        "--seed",
        "4",
        "--out",
        s(&scenes),
    ]);
    let plans = ok(&[
        "plan",
        "--robot",
        robot,
        "--scenarios",
        s(&scenes),
        "--json",
    ]);
    let plans: serde_json::Value = serde_json::from_str(&plans).unwrap();
    let plans = plans["results"].as_array().unwrap();
    assert_eq!(plans.len(), 3);
    assert!(plans.iter().all(|p| p["solvable"] == true), "{plans:?}");

    // Two iterations of the smoke recipe on its straight scenes.
    let run = dir.join("run");
    ok(&[
        "train",
        "baseline",
        "--config",
        SMOKE,
        "--robot",
        robot,
        "--out",
        s(&run),
        "--seed",
        "1",
        "--quiet",
        "--stop-at-env-steps",
        "2000",
    ]);
    let checkpoint = run.join("checkpoint.ckpt");

    // Exported: the weights name the robot.
    let weights = dir.join("robot.wlw");
    ok(&[
        "export",
        "--policy",
        s(&checkpoint),
        "--out",
        s(&weights),
        "--kind",
        "straight",
        "--calibration",
        "300",
        "--holdout",
        "100",
        "--qat-steps",
        "0",
    ]);

    // Evaluated on its robot.
    let eval = ok(&[
        "eval",
        "--robot",
        robot,
        "--policy",
        s(&weights),
        "--generated",
        "2",
        "--kind",
        "straight",
        "--max-expansions",
        "0",
        "--json",
    ]);
    let eval: serde_json::Value = serde_json::from_str(&eval).unwrap();
    assert_eq!(eval["scenarios"].as_array().unwrap().len(), 2);

    // The demo on the in-process bus: every frame goes to the robot's nodes (21 to 36).
    let straight = dir.join("straight.json");
    ok(&[
        "generate",
        "--robot",
        robot,
        "--kind",
        "straight",
        "--count",
        "1",
        "--seed",
        "2",
        "--out",
        s(&straight),
    ]);
    let demo = dir.join("demo");
    let out = wheelleg(&[
        "demo",
        "--robot",
        robot,
        "--policy",
        s(&weights),
        "--scenarios",
        s(&straight),
        "--out",
        s(&demo),
    ]);
    // A two-iteration policy may not reach the target; the loop must run and log the bus.
    let log = std::fs::read_to_string(demo.join("bus.log"))
        .unwrap_or_else(|e| panic!("no bus log ({e}): {}", String::from_utf8_lossy(&out.stderr)));
    let mut frames = 0;
    for line in log.lines() {
        // `(time) iface ID#DATA`: the node id is the CAN id's upper six bits.
        let id = line
            .split_whitespace()
            .nth(2)
            .unwrap()
            .split('#')
            .next()
            .unwrap();
        let node = u32::from_str_radix(id, 16).unwrap() >> 5;
        assert!((21..=36).contains(&node), "{line}");
        frames += 1;
    }
    assert!(frames > 100, "{frames} frames");
    (checkpoint, weights)
}

#[test]
fn the_second_robot_goes_through_generate_plan_train_export_eval_and_demo() {
    let dir = scratch("strider");
    let report = ok(&["robot", "check", STRIDER, "--json"]);
    let report: serde_json::Value = serde_json::from_str(&report).unwrap();
    assert!(report["behaviours"]
        .as_array()
        .unwrap()
        .iter()
        .all(|b| b["available"] == true));
    // Each scene fence's passing pose, fitted to it (`sim/src/generate/fit.rs`).
    let fences = &report["fences"];
    assert_eq!(fences["lift"]["clearance_steps"], 2, "{fences}");
    assert_eq!(fences["squeeze"]["track_steps"], -10, "{fences}");

    let (checkpoint, weights) = through_the_chain(STRIDER, &dir);
    let inspect = ok(&["inspect", s(&weights)]);
    assert!(inspect.contains("strider"), "{inspect}");

    // Resumed for the shipped robot: refused, naming both.
    let err = refused(&[
        "train",
        "baseline",
        "--config",
        SMOKE,
        "--out",
        s(&dir.join("run")),
        "--seed",
        "1",
        "--quiet",
        "--resume",
    ]);
    names_both_robots(&err);
    // Evaluated on the shipped robot: refused, checkpoint and weights alike.
    for policy in [&weights, &checkpoint] {
        let err = eval_refused(&["--policy", s(policy)]);
        names_both_robots(&err);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_robot_on_another_action_lattice_goes_through_the_chain() {
    // The strider stepping 6.25 cm, 7.5 degrees and 3 cm of track (its clearance step kept):
    // four moves to a scene cell, twelve turns to a quarter turn.
    let dir = scratch("coarse");
    let text = std::fs::read_to_string(STRIDER).unwrap();
    let coarse = text
        .replace("move_step_m = 0.05", "move_step_m = 0.0625")
        .replace("yaw_step_deg = 5.0", "yaw_step_deg = 7.5")
        .replace("track_step_m = 0.02", "track_step_m = 0.03");
    assert_ne!(coarse, text);
    let robot = dir.join("strider-coarse.toml");
    std::fs::write(&robot, coarse).unwrap();
    let robot = s(&robot);
    let report = ok(&["robot", "check", robot, "--json"]);
    let report: serde_json::Value = serde_json::from_str(&report).unwrap();
    for fence in ["lift", "spread", "squeeze"] {
        assert!(
            report["fences"][fence]["track_steps"].is_i64(),
            "{fence}: {}",
            report["fences"]
        );
    }

    let (_, weights) = through_the_chain(robot, &dir);
    let inspect = ok(&["inspect", s(&weights)]);
    assert!(
        inspect.contains("move 0.0625 m, yaw 7.5 deg, clearance 0.02 m, track 0.03 m"),
        "{inspect}"
    );
    // The same robot on the paper's lattice is another robot to a policy: refused, naming the
    // lattice.
    let err = eval_refused(&["--robot", STRIDER, "--policy", s(&weights)]);
    assert!(err.contains("action lattice differs"), "{err}");
    // A lattice the scenes cannot line up with is refused, naming the key.
    let crooked = dir.join("crooked.toml");
    std::fs::write(
        &crooked,
        text.replace("yaw_step_deg = 5.0", "yaw_step_deg = 7.0"),
    )
    .unwrap();
    let err = refused(&[
        "generate",
        "--robot",
        s(&crooked),
        "--kind",
        "straight",
        "--count",
        "1",
        "--out",
        s(&dir.join("crooked.json")),
    ]);
    assert!(err.contains("actions.yaw_step_deg = 7"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
