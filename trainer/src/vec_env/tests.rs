use super::*;
use wheelleg_sim::generate::Behaviour;

fn run(threads: usize, steps: usize, restore_at: Option<usize>) -> (Vec<f32>, Vec<f32>) {
    run_with(threads, steps, restore_at, None)
}

/// Steps 5 envs with fixed pseudo-random choices; `failures`: (memory per env,
/// re-sampling probability). Returns every reward and the last states.
fn run_with(
    threads: usize,
    steps: usize,
    restore_at: Option<usize>,
    failures: Option<(usize, f64)>,
) -> (Vec<f32>, Vec<f32>) {
    let kind = SceneKind::Behaviour(Behaviour::Around);
    let n = 5;
    let config = EnvConfig {
        max_steps: 20,
        ..EnvConfig::default()
    };
    let fresh = || {
        let mut v = VecEnv::new(kind, n, 9, config, threads).unwrap();
        if let Some((per_env, probability)) = failures {
            v.set_failure_memory(per_env, probability);
        }
        v
    };
    let mut v = fresh();
    let (mut h, mut s) = (vec![0.0; n * HEIGHT_MAP_CELLS], vec![0.0; n * STATE_LEN]);
    let mut rewards = Vec::new();
    for t in 0..steps {
        if restore_at == Some(t) {
            let (snap, memory) = (v.snapshot(), v.failure_snapshot());
            v = fresh();
            v.restore(9, &snap).unwrap();
            v.restore_failures(&memory).unwrap();
        }
        let choices: Vec<u8> = (0..n * DIMS).map(|k| ((k * 7 + t * 3) % 3) as u8).collect();
        rewards.extend(v.step(&choices, &mut h, &mut s).iter().map(|r| r.reward));
    }
    (rewards, s)
}

#[test]
fn thread_count_and_restores_do_not_change_results() {
    let one = run(1, 150, None);
    assert_eq!(one, run(2, 150, None));
    assert_eq!(one, run(2, 150, Some(77)));
    let resampled = run_with(1, 150, None, Some((4, 0.5)));
    assert_eq!(resampled, run_with(2, 150, Some(77), Some((4, 0.5))));
    assert_ne!(resampled, one, "failed scenes did come back");
    assert_eq!(
        one,
        run_with(1, 150, None, Some((4, 0.0))),
        "never re-sampling changes nothing"
    );
}

#[test]
fn failed_scenes_come_back_and_staged_ones_do_not() {
    let kind = SceneKind::Behaviour(Behaviour::Straight);
    let n = 3;
    let config = EnvConfig {
        max_steps: 3,
        ..EnvConfig::default()
    };
    let mut v = VecEnv::new(kind, n, 4, config, 1).unwrap();
    v.set_failure_memory(2, 1.0);
    let first: Vec<String> = v.slots.iter().map(|s| s.scenario.name.clone()).collect();
    let (mut h, mut s) = (vec![0.0; n * HEIGHT_MAP_CELLS], vec![0.0; n * STATE_LEN]);
    // Idle for 3 steps: every episode runs out of steps, and the memory offers the same
    // scene again with probability 1.
    let idle: Vec<u8> = vec![1; n * DIMS];
    for _ in 0..3 {
        v.step(&idle, &mut h, &mut s);
    }
    let again: Vec<String> = v.slots.iter().map(|s| s.scenario.name.clone()).collect();
    assert_eq!(first, again);
    assert!(v
        .failure_snapshot()
        .iter()
        .all(|json| json.contains("\"scenarios\": []")));
    // Scenes drawn at a start stage below 1 are not the task; their failures are not kept.
    let mut staged = VecEnv::with_stage(kind, StartYaw::Any, 0.5, n, 4, config, 1).unwrap();
    staged.set_failure_memory(2, 1.0);
    let staged_first: Vec<String> = staged
        .slots
        .iter()
        .map(|s| s.scenario.name.clone())
        .collect();
    for _ in 0..3 {
        staged.step(&idle, &mut h, &mut s);
    }
    assert!(staged
        .slots
        .iter()
        .zip(&staged_first)
        .all(|(slot, name)| slot.scenario.name != *name && slot.stage == 0.5));
    // Without the memory the next scenes are fresh ones.
    let mut plain = VecEnv::new(kind, n, 4, config, 1).unwrap();
    for _ in 0..3 {
        plain.step(&idle, &mut h, &mut s);
    }
    assert!(plain
        .slots
        .iter()
        .zip(&first)
        .all(|(slot, name)| slot.scenario.name != *name));
}

#[test]
fn the_composed_and_exit_shares_mix_their_scenes_in_deterministically() {
    let names = |share: f64, exit_share: f64| -> Vec<String> {
        let scenes = Scenes {
            kind: SceneKind::Complex,
            start_yaw: StartYaw::Any,
            stage: 1.0,
            composed_share: share,
            exit_share,
            exit_behaviour: Behaviour::Squeeze,
        };
        let v = VecEnv::with_scenes(scenes, 40, 5, EnvConfig::default(), 1).unwrap();
        v.snapshot()
            .iter()
            .map(|s| {
                wheelleg_sim::scenario_file::parse(
                    &s.scenario_json,
                    &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
                )
                .unwrap()[0]
                    .name
                    .clone()
            })
            .collect()
    };
    let family = |n: &String| n.split('-').next().unwrap_or("").to_string();
    assert!(names(0.0, 0.0).iter().all(|n| family(n) == "complex"));
    assert!(names(1.0, 0.0).iter().all(|n| family(n) == "composed"));
    assert!(names(0.0, 1.0)
        .iter()
        .all(|n| n.starts_with("squeeze-exit-")));
    let half = names(0.5, 0.0);
    let composed = half.iter().filter(|n| family(n) == "composed").count();
    assert!((10..=30).contains(&composed), "{composed} of 40 composed");
    assert_eq!(half, names(0.5, 0.0), "the same seed, the same mix");
    let thirds = names(0.4, 0.3);
    let exits = thirds
        .iter()
        .filter(|n| n.starts_with("squeeze-exit-"))
        .count();
    assert!((4..=24).contains(&exits), "{exits} of 40 exit scenes");
    assert_eq!(thirds, names(0.4, 0.3));
}

#[test]
fn a_composed_share_set_during_a_run_applies_to_the_scenes_drawn_after_it() {
    let scenes = Scenes {
        kind: SceneKind::Complex,
        start_yaw: StartYaw::Any,
        stage: 1.0,
        composed_share: 0.0,
        exit_share: 0.0,
        exit_behaviour: Behaviour::Squeeze,
    };
    let mut v = VecEnv::with_scenes(scenes, 8, 5, EnvConfig::default(), 1).unwrap();
    let family = |v: &VecEnv| -> Vec<String> {
        v.slots
            .iter()
            .map(|s| s.scenario.name.split('-').next().unwrap_or("").to_string())
            .collect()
    };
    assert!(family(&v).iter().all(|f| f == "complex"));
    v.set_composed_share(1.0);
    // The scenes already drawn stay; the next episode of each env is composed.
    assert!(family(&v).iter().all(|f| f == "complex"));
    let (scenes, config) = (v.scenes, v.config);
    for (i, slot) in v.slots.iter_mut().enumerate() {
        slot.reset(scenes, config, i);
    }
    assert!(
        family(&v).iter().all(|f| f == "composed"),
        "{:?}",
        family(&v)
    );
}
