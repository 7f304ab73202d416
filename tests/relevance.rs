//! `wheelleg relevance` as a user meets it: a checkpoint and a scenario file in, a PNG and the
//! per-obstacle figures out; bad input refused with a message and a non-zero exit status.
//!
//! The checkpoint is a freshly initialised network saved here, so the test needs no trained run.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;
use std::process::{Command, Output};
use wheelleg_trainer::checkpoint::{Checkpoint, NetworkRecord};
use wheelleg_trainer::network::init_policy;
use wheelleg_trainer::network_f32::Architecture;
use wheelleg_trainer::ppo::Adam;

fn wheelleg(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_wheelleg"))
        .args(args)
        .output()
        .expect("the wheelleg binary runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-rel-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A tiny valid checkpoint: a random policy of the default architecture.
fn checkpoint(dir: &std::path::Path) -> PathBuf {
    let net = init_policy(
        &Architecture::default_policy(),
        &mut ChaCha8Rng::seed_from_u64(5),
    );
    let path = dir.join("policy.ckpt");
    Checkpoint {
        kind: "test".into(),
        config_toml: String::new(),
        seed: 5,
        iteration: 0,
        env_steps: 0,
        adam: Adam::new(&net),
        network: NetworkRecord::from_network(&net),
        sampler_word_pos: 0,
        envs: Vec::new(),
        elapsed_s: 0.0,
    }
    .save(&path)
    .unwrap();
    path
}

#[test]
fn relevance_writes_the_figure_and_one_figure_per_obstacle() {
    let dir = scratch("ok");
    let policy = checkpoint(&dir);
    let scenes = dir.join("complex.json");
    let out = wheelleg(&[
        "generate",
        "--kind",
        "complex",
        "--count",
        "3",
        "--seed",
        "4",
        "--out",
        scenes.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let png = dir.join("relevance.png");
    let out = wheelleg(&[
        "relevance",
        "--policy",
        policy.to_str().unwrap(),
        "--scenarios",
        scenes.to_str().unwrap(),
        "--name",
        "complex-1",
        "--out",
        png.to_str().unwrap(),
        "--json",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&scenes).unwrap()).unwrap();
    let obstacles = file["scenarios"][1]["obstacles"].as_array().unwrap().len();
    let rows = json["obstacles"].as_array().unwrap();
    assert_eq!(rows.len(), obstacles);
    for (i, row) in rows.iter().enumerate() {
        assert_eq!(row["index"].as_u64(), Some(i as u64));
        assert!(row["relevance_m"].as_f64().unwrap() >= 0.0, "{row}");
    }
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");

    // The table form names the scene.
    let out = wheelleg(&[
        "relevance",
        "--policy",
        policy.to_str().unwrap(),
        "--scenario",
        scenes.to_str().unwrap(),
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("complex-0"),
        "{}",
        text(&out.stdout)
    );
}

#[test]
fn relevance_refuses_bad_input_clearly() {
    let dir = scratch("bad");
    let policy = checkpoint(&dir);
    let scenes = dir.join("straight.json");
    let out = wheelleg(&[
        "generate",
        "--kind",
        "straight",
        "--count",
        "1",
        "--out",
        scenes.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let png = dir.join("r.png");
    let run = |policy: &str, name: &str| {
        wheelleg(&[
            "relevance",
            "--policy",
            policy,
            "--scenarios",
            scenes.to_str().unwrap(),
            "--name",
            name,
            "--out",
            png.to_str().unwrap(),
        ])
    };
    let out = run(policy.to_str().unwrap(), "straight-3");
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("no scenario of that name"),
        "{}",
        text(&out.stderr)
    );

    let junk = dir.join("junk.ckpt");
    std::fs::write(&junk, b"not a checkpoint at all, just text").unwrap();
    let out = run(junk.to_str().unwrap(), "straight-0");
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("magic"), "{}", text(&out.stderr));
}
