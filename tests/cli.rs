//! The command line as a user meets it: generate → plan → render, inspect, robot descriptions,
//! and clear refusals of bad input with a non-zero exit status.

use rand::SeedableRng;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{quantize, Calibration, RangeMethod};

mod support;

fn wheelleg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_wheelleg"))
        .args(args)
        .output()
        .expect("the wheelleg binary runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn generate_plan_and_render_a_scenario_file() {
    let dir = scratch("plan");
    let file = dir.join("straight.json");
    let file_arg = file.to_str().unwrap();
    let out = wheelleg(&[
        "generate", "--kind", "straight", "--count", "3", "--seed", "2", "--out", file_arg,
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));

    let out = wheelleg(&["plan", "--scenarios", file_arg, "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let results = json["results"].as_array().unwrap();
    assert_eq!(results.len(), 3);
    for r in results {
        assert_eq!(r["solvable"], serde_json::Value::Bool(true), "{r}");
        // 0.5 to 1.0 m at most 0.0707 m per step, and no detour is needed.
        let steps = r["steps"].as_u64().unwrap();
        assert!((7..=20).contains(&steps), "{r}");
    }

    // One planner pass serves later evaluations: the same ratio as planning during the eval.
    let plan_file = dir.join("plan.json");
    std::fs::write(&plan_file, &out.stdout).unwrap();
    let policy = concat!(env!("CARGO_MANIFEST_DIR"), "/weights/policy.wlw");
    let eval = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--policy",
            policy,
            "--scenarios",
            file_arg,
            "--json",
        ];
        args.extend_from_slice(extra);
        let out = wheelleg(&args);
        assert!(out.status.success(), "{}", text(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let planned = eval(&["--stack", "policy"]);
    assert_eq!(planned["arrival"], false, "{planned}");
    assert!(planned["guard_margin_m"].is_null(), "{planned}");
    // Every scenario is in the split by what stands beside its target, exactly once.
    let split = planned["by_target_beside"].as_array().unwrap();
    let counted: u64 = split.iter().map(|b| b["scenarios"].as_u64().unwrap()).sum();
    assert_eq!(
        counted as usize,
        planned["scenarios"].as_array().unwrap().len()
    );
    // The robot's stack, on the policy's own map: the guard and the arrival rule.
    let stack = eval(&["--guard-map", "policy"]);
    assert_eq!(stack["arrival"], true, "{stack}");
    assert!(stack["guard_margin_m"].is_number(), "{stack}");
    assert_eq!(stack["guard_cell_m"].as_f64(), Some(0.05), "{stack}");
    // The guard on a finer map than the policy's: the default stack.
    let fine = eval(&[]);
    assert_eq!(fine["guard_cell_m"].as_f64(), Some(0.01), "{fine}");
    assert_eq!(fine["arrival"], true, "{fine}");
    // And the search for the last metres: reported, and never worse on scenes the stack
    // already solves (it only runs after 10 decisions near the target).
    let searched = eval(&["--stack", "full", "--lookahead-search", "0"]);
    assert!(
        searched["last_metres"]["searches"].is_number(),
        "{searched}"
    );
    assert!(
        searched["success_rate"].as_f64() >= fine["success_rate"].as_f64(),
        "{searched}"
    );
    assert!(fine["last_metres"].is_null(), "{fine}");
    // The look-ahead: reported, and no episode of these open scenes is longer for it (its
    // rollouts keep the rule's own action unless another arrives strictly sooner).
    let looked = eval(&[
        "--stack",
        "full",
        "--lookahead-search",
        "0",
        "--last-metres",
        "0",
    ]);
    assert!(looked["last_metres"].is_null(), "{looked}");
    assert_eq!(looked["lookahead"]["candidates"], 8, "{looked}");
    assert!(
        looked["lookahead"]["decisions"].as_u64() > Some(0),
        "{looked}"
    );
    assert!(fine["lookahead"].is_null(), "{fine}");
    let steps = |report: &serde_json::Value| -> Vec<(bool, u64)> {
        report["scenarios"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| {
                (
                    s["success"].as_bool().unwrap(),
                    s["steps"].as_u64().unwrap(),
                )
            })
            .collect()
    };
    for (with, without) in steps(&looked).into_iter().zip(steps(&fine)) {
        assert!(with.0 >= without.0, "{looked}");
        assert!(!without.0 || with.1 <= without.1, "{looked}");
    }
    // With the search for a shorter way: reported, no success lost, fewer steps in all.
    let shorter = eval(&["--stack", "full", "--last-metres", "0"]);
    assert_eq!(shorter["lookahead"]["search_expansions"], 500, "{shorter}");
    assert!(shorter["success_rate"].as_f64() >= looked["success_rate"].as_f64());
    let total = |report: &serde_json::Value| -> u64 { steps(report).iter().map(|s| s.1).sum() };
    assert!(total(&shorter) < total(&looked), "{shorter}\n{looked}");
    // A bad value, a layer option for a stack without that layer, a rule the layers cannot
    // build on: each an error that names the option.
    for (extra, named) in [
        (&["--guard-map", "coarse"][..], "--guard-map"),
        (
            &["--stack", "policy", "--guard-margin", "0.01"],
            "--guard-margin",
        ),
        (&["--rule", "argmax"], "--rule argmax"),
    ] {
        let mut args = vec!["eval", "--policy", policy, "--scenarios", file_arg];
        args.extend_from_slice(extra);
        let bad = wheelleg(&args);
        assert!(!bad.status.success(), "{extra:?}");
        let stderr = text(&bad.stderr);
        assert!(stderr.contains(named), "{extra:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{extra:?}: {stderr}");
    }
    let table = wheelleg(&["eval", "--policy", policy, "--scenarios", file_arg]);
    assert!(table.status.success(), "{}", text(&table.stderr));
    let table = text(&table.stdout);
    assert!(table.contains("beside the target"), "{table}");
    assert!(table.contains("  nothing"), "{table}");
    let cached = eval(&[
        "--stack",
        "policy",
        "--planner-results",
        plan_file.to_str().unwrap(),
    ]);
    assert!(planned["steps_vs_shortest"].is_number(), "{planned}");
    assert_eq!(planned["steps_vs_shortest"], cached["steps_vs_shortest"]);
    assert!(planned["median_steps_vs_shortest"].is_number(), "{planned}");
    assert_eq!(
        planned["median_steps_vs_shortest"],
        cached["median_steps_vs_shortest"]
    );
    let other = dir.join("other-plan.json");
    std::fs::write(
        &other,
        r#"{"results":[{"name":"elsewhere","steps":9,"shortest":true}]}"#,
    )
    .unwrap();
    let out = wheelleg(&[
        "eval",
        "--policy",
        policy,
        "--scenarios",
        file_arg,
        "--planner-results",
        other.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("results name no scenario"),
        "{}",
        text(&out.stderr)
    );

    let pictures = dir.join("pictures");
    let out = wheelleg(&[
        "render",
        "--scenarios",
        file_arg,
        "--out",
        pictures.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for name in [
        "straight-0.png",
        "straight-0-heightmap.png",
        "straight-2.png",
    ] {
        let png = std::fs::read(pictures.join(name)).unwrap();
        assert_eq!(&png[1..4], b"PNG", "{name} is a PNG");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `plan --jobs` plans scenarios side by side and still prints them in file order, the same
/// output for any number of threads.
#[test]
fn plan_gives_the_same_output_for_any_number_of_jobs() {
    let dir = scratch("plan-jobs");
    let file = dir.join("mixed.json");
    let file_arg = file.to_str().unwrap();
    let out = wheelleg(&[
        "generate", "--kind", "complex", "--count", "5", "--seed", "3", "--out", file_arg,
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let plan = |jobs: &str| {
        let out = wheelleg(&[
            "plan",
            "--scenarios",
            file_arg,
            "--json",
            "--max-expansions",
            "300",
            "--jobs",
            jobs,
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        text(&out.stdout)
    };
    let one = plan("1");
    let json: serde_json::Value = serde_json::from_str(&one).unwrap();
    let names: Vec<&str> = json["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["name"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 5);
    assert_eq!(one, plan("2"));
    assert_eq!(one, plan("3"));
    let out = wheelleg(&["plan", "--scenarios", file_arg, "--jobs", "0"]);
    assert!(!out.status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_scenario_files_fail_every_command_with_the_reason() {
    let dir = scratch("bad");
    let file = dir.join("bad.json");
    std::fs::write(
        &file,
        r#"{"scenarios":[{"name":"oops","robot":{"x":0,"y":0,"yaw_deg":0},"target":{"x":0.8,"y":0},
            "obstacles":[{"kind":"pyramid","x":0.375,"y":0.125,"yaw_deg":0}]}]}"#,
    )
    .unwrap();
    let file_arg = file.to_str().unwrap();
    for args in [
        vec!["plan", "--scenarios", file_arg],
        vec![
            "render",
            "--scenarios",
            file_arg,
            "--out",
            dir.to_str().unwrap(),
        ],
    ] {
        let out = wheelleg(&args);
        assert!(!out.status.success());
        let message = text(&out.stderr);
        assert!(
            message.contains("oops") && message.contains("obstacles[0].kind"),
            "{message}"
        );
    }
    let out = wheelleg(&["generate", "--kind", "maze", "--out", file_arg]);
    assert!(!out.status.success());
    // Refused naming the flag and the kinds there are.
    let message = text(&out.stderr);
    assert!(
        message.contains("invalid value 'maze' for '--kind")
            && message.contains("straight, around, lift, spread, squeeze, complex, composed"),
        "{message}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

fn random_policy_file(dir: &Path) -> PathBuf {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let height = vec![0.1f32; 32 * 32];
    let state = vec![0.12, 0.36, 0.8, 0.0];
    let calibration =
        Calibration::from_observations(&network, [(height.as_slice(), state.as_slice())]);
    let bytes = quantize(&network, &calibration, RangeMethod::MinMax)
        .unwrap()
        .to_bytes()
        .unwrap();
    let path = dir.join("policy.wlw");
    std::fs::write(&path, bytes).unwrap();
    path
}

#[test]
fn inspect_shows_the_architecture_and_refuses_damaged_files() {
    let dir = scratch("inspect");
    let policy = random_policy_file(&dir);
    let out = wheelleg(&["inspect", policy.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report = text(&out.stdout);
    for expected in [
        "32x32x1 -> 16x16x16",
        "516 -> 128 relu",
        "128 -> 15",
        "82288 parameters",
    ] {
        assert!(report.contains(expected), "{report}");
    }
    let mut bytes = std::fs::read(&policy).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x40;
    let damaged = dir.join("damaged.wlw");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = wheelleg(&["inspect", damaged.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("checksum"),
        "{}",
        text(&out.stderr)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_reader_that_goes_away_ends_the_output_quietly() {
    use std::io::Read;
    use std::process::Stdio;
    let dir = scratch("pipe");
    let policy = random_policy_file(&dir);
    // 500 scenario results, about 110 KB of JSON: more than a pipe holds, so the writer is
    // still writing when the reader closes its end.
    let mut child = Command::new(env!("CARGO_BIN_EXE_wheelleg"))
        .args([
            "eval",
            "--policy",
            policy.to_str().unwrap(),
            "--generated",
            "500",
            "--kind",
            "straight",
            "--max-expansions",
            "0",
            "--json",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 16];
    child.stdout.take().unwrap().read_exact(&mut first).unwrap();
    assert_eq!(first[0], b'{', "JSON output starts");
    // The read end is dropped here, like `| head -c 16`.
    let out = child.wait_with_output().unwrap();
    let stderr = text(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.code(), Some(141), "{stderr}");
}

const SHIPPED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/wheelleg.toml");
const STRIDER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/robots/strider.toml");

#[test]
fn robot_check_reports_what_each_robot_allows() {
    let out = wheelleg(&["robot", "check", SHIPPED]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let report = text(&out.stdout);
    assert!(report.contains("robot:           wheelleg"), "{report}");
    assert!(report.contains("squeeze   yes"), "{report}");

    let picture = scratch("robot-picture").join("strider.png");
    let out = wheelleg(&[
        "robot",
        "check",
        STRIDER,
        "--picture",
        picture.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let png = std::fs::read(&picture).unwrap();
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    std::fs::remove_file(&picture).unwrap();

    let out = wheelleg(&["robot", "check", STRIDER, "--json"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["robot"], "strider");
    let behaviours = json["behaviours"].as_array().unwrap();
    assert_eq!(behaviours.len(), 5);
    // The larger robot lifts over taller bars than the shipped one can.
    assert!(json["lift"]["height_m"].as_f64().unwrap() > 0.25, "{json}");
}

#[test]
fn robot_urdf_written_and_imported_gives_the_same_description() {
    let dir = scratch("robot-urdf");
    for (name, file) in [("wheelleg", SHIPPED), ("strider", STRIDER)] {
        let urdf = dir.join(format!("{name}.urdf"));
        let out = wheelleg(&["robot", "urdf", file, "--out", urdf.to_str().unwrap()]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let back = dir.join(format!("{name}.toml"));
        let out = wheelleg(&[
            "robot",
            "import-urdf",
            urdf.to_str().unwrap(),
            "--out",
            back.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        // The same robot: the reports of both files are identical.
        let a = wheelleg(&["robot", "check", file, "--json"]);
        let b = wheelleg(&["robot", "check", back.to_str().unwrap(), "--json"]);
        assert_eq!(text(&a.stdout), text(&b.stdout));
        // An existing file is never overwritten.
        let again = wheelleg(&[
            "robot",
            "import-urdf",
            urdf.to_str().unwrap(),
            "--out",
            back.to_str().unwrap(),
        ]);
        assert!(!again.status.success());
        assert!(
            text(&again.stderr).contains("exists"),
            "{}",
            text(&again.stderr)
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn robot_refuses_bad_descriptions_and_urdfs_by_name() {
    let dir = scratch("robot-bad");
    let bad = dir.join("bad.toml");
    let shipped = std::fs::read_to_string(SHIPPED).unwrap();
    std::fs::write(&bad, shipped.replacen("shank_m = 0.16", "shank_m = 0.0", 1)).unwrap();
    let out = wheelleg(&["robot", "check", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("legs.shank_m") && err.contains("bad.toml"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let urdf = dir.join("arm.urdf");
    std::fs::write(
        &urdf,
        "<robot name=\"arm\"><link name=\"base\"/><link name=\"a\"/>\
         <joint name=\"j\" type=\"revolute\"><parent link=\"base\"/><child link=\"a\"/>\
         <axis xyz=\"0 0 1\"/><limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint></robot>",
    )
    .unwrap();
    let out = wheelleg(&[
        "robot",
        "import-urdf",
        urdf.to_str().unwrap(),
        "--out",
        dir.join("arm.toml").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("link 'base'") && err.contains("collision box"),
        "{err}"
    );
    assert!(!dir.join("arm.toml").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_policy_is_refused_for_a_robot_it_was_not_trained_for() {
    let dir = scratch("robot-weights");
    let scenes = dir.join("straight.json");
    let out = wheelleg(&[
        "generate",
        "--kind",
        "straight",
        "--count",
        "2",
        "--seed",
        "3",
        "--out",
        scenes.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let eval = |weights: &std::path::Path| {
        wheelleg(&[
            "eval",
            "--policy",
            weights.to_str().unwrap(),
            "--scenarios",
            scenes.to_str().unwrap(),
            "--max-expansions",
            "0",
            "--json",
        ])
    };
    // The shipped robot's record: the same tensors, the same episodes as the version 2 file.
    let shipped = dir.join("shipped-v3.wlw");
    std::fs::write(
        &shipped,
        support::shipped_network_for(&wheelleg_robot::RobotDescription::shipped()),
    )
    .unwrap();
    let v3 = eval(&shipped);
    assert!(v3.status.success(), "{}", text(&v3.stderr));
    let v2 = eval(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/weights/policy.wlw"
    )));
    let episodes = |out: &Output| {
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()["scenarios"].clone()
    };
    assert_eq!(episodes(&v3), episodes(&v2));

    // Another robot's: refused by eval and by the demo, naming both robots.
    let strider = wheelleg_robot::RobotDescription::load(std::path::Path::new(STRIDER)).unwrap();
    let other = dir.join("strider.wlw");
    std::fs::write(&other, support::shipped_network_for(&strider)).unwrap();
    let out = eval(&other);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("trained for robot 'strider'") && err.contains("robot 'wheelleg'"),
        "{err}"
    );
    let out = wheelleg(&[
        "demo",
        "--policy",
        other.to_str().unwrap(),
        "--out",
        dir.join("demo").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("trained for robot 'strider'"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn firmware_loop_flags_are_refused_without_the_firmware_in_the_loop() {
    for flags in [
        &["--clock", "emulated"][..],
        &["--inject-decision-ms", "500"][..],
        &["--json"][..],
    ] {
        let mut args = vec!["demo", "--out"];
        let dir = scratch("demo-flags");
        let dir_arg = dir.to_str().unwrap().to_owned();
        args.push(&dir_arg);
        args.extend_from_slice(flags);
        let out = wheelleg(&args);
        assert!(!out.status.success(), "{flags:?} was taken");
        let stderr = text(&out.stderr);
        assert!(
            stderr.contains(flags[0]) && stderr.contains("--controller qemu"),
            "{flags:?}: {stderr}"
        );
    }
}
