use super::*;

#[test]
fn defaults_follow_the_paper_and_round_trip() {
    let c = TrainConfig::default();
    assert_eq!(c.run.steps_per_iteration, 10_000);
    assert_eq!(
        c.architecture(),
        crate::network_f32::Architecture::default_policy()
    );
    assert_eq!(TrainConfig::from_toml(&c.to_toml()).unwrap(), c);
}

#[test]
fn every_shipped_config_and_every_stored_config_loads() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut loaded = 0;
    for folder in ["configs", "configs/comparisons"] {
        for entry in std::fs::read_dir(root.join(folder)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
                loaded += 1;
            }
        }
    }
    assert!(loaded >= 15, "{loaded} configs");
    // What `--resume` reads back from run folders that earlier versions wrote (while retired
    // keys existed, so they hold them): one of each kind, kept as fixtures.
    let mut stored = 0;
    for entry in std::fs::read_dir(root.join("trainer/tests/fixtures/stored-configs")).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        TrainConfig::from_toml(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        stored += 1;
    }
    assert!(stored >= 20, "{stored} stored configs");
}

#[test]
fn retired_keys_at_their_off_values_load_and_resume_and_switched_on_are_named() {
    let c = TrainConfig::default();
    let retired = "planner_demonstrations = 0\nplanner_demo_expansions = 2000\n\
                   planner_demo_target_beside_only = false\nreplay_planner_share = 0.0\n";
    let stored = c
        .to_toml()
        .replace("[curriculum]\n", &format!("[curriculum]\n{retired}"));
    assert!(stored.contains("planner_demonstrations"), "{stored}");
    assert_eq!(TrainConfig::from_toml(&stored).unwrap(), c);
    assert_eq!(
        c.changes_from_stored(&stored, &["replay_balance"]).unwrap(),
        Vec::<String>::new()
    );
    for on in ["planner_demonstrations = 800", "replay_planner_share = 0.5"] {
        let e = TrainConfig::from_toml(&format!("[curriculum]\n{on}\n"))
            .unwrap_err()
            .to_string();
        let key = on.split(' ').next().unwrap();
        assert!(
            e.contains(&format!("curriculum.{key}")) && e.contains("removed"),
            "{e}"
        );
        let e = c
            .changes_from_stored(&format!("[curriculum]\n{on}\n"), &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains(key), "{e}");
    }
}

#[test]
fn a_config_extends_its_base_key_by_key_and_a_cycle_is_named() {
    let dir = std::env::temp_dir().join(format!("wheelleg-extends-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let write = |name: &str, text: &str| std::fs::write(dir.join(name), text).unwrap();
    write(
        "base.toml",
        "[run]\ntotal_env_steps = 7000000\nnum_envs = 10\nsteps_per_iteration = 1000\n\
         [ppo]\ngamma = 0.9\n",
    );
    write(
        "sub/variant.toml",
        "extends = \"../base.toml\"\n[run]\ntotal_env_steps = 9000000\n",
    );
    let c = TrainConfig::load(&dir.join("sub/variant.toml")).unwrap();
    assert_eq!(c.run.total_env_steps, 9_000_000, "the variant's own key");
    assert_eq!(c.run.num_envs, 10, "the base's key beside it");
    assert_eq!(c.ppo.gamma, 0.9, "the base's other table");
    assert_eq!(
        c.ppo.epochs,
        PpoConfig::default().epochs,
        "the defaults below both"
    );

    write("a.toml", "extends = \"b.toml\"\n");
    write("b.toml", "extends = \"a.toml\"\n");
    let e = TrainConfig::load(&dir.join("a.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("extend one another"), "{e}");
    write("c.toml", "extends = \"missing.toml\"\n");
    let e = TrainConfig::load(&dir.join("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("extends missing.toml") && e.contains("cannot read"),
        "{e}"
    );
    write("d.toml", "extends = \"base.toml\"\n[run]\nnum_env = 3\n");
    let e = TrainConfig::load(&dir.join("d.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("num_env"), "a typo in a variant is named: {e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_learning_rate_anneals_linearly_over_its_span_and_may_change_on_resume() {
    let mut c =
        TrainConfig::from_toml("[run]\ntotal_env_steps = 30000000\n[ppo]\nlearning_rate = 0.001\n")
            .unwrap();
    assert_eq!(
        c.ppo.learning_rate_at(25_000_000, 30_000_000),
        0.001,
        "constant"
    );
    let stored = c.to_toml();
    c.ppo.learning_rate_final = Some(0.0001);
    c.ppo.anneal_start_env_steps = 20_000_000;
    c.validate().unwrap();
    let mut lower = c.clone();
    lower.ppo.learning_rate = 0.0005;
    assert!(lower.changes_from_stored(&stored, &[]).unwrap().is_empty());
    let at = |steps| c.ppo.learning_rate_at(steps, 30_000_000);
    assert_eq!(at(10_000_000), 0.001, "before the span");
    assert_eq!(at(20_000_000), 0.001, "at its start");
    assert!(
        (at(25_000_000) - 0.00055).abs() < 1e-12,
        "{}",
        at(25_000_000)
    );
    assert!((at(30_000_000) - 0.0001).abs() < 1e-12, "at the end");
    assert!((at(40_000_000) - 0.0001).abs() < 1e-12, "past the end");
    assert!(c.changes_from_stored(&stored, &[]).unwrap().is_empty());
    c.ppo.anneal_start_env_steps = 30_000_000;
    let e = c.validate().unwrap_err().to_string();
    assert!(e.contains("ppo.anneal_start_env_steps"), "{e}");
}

#[test]
fn every_committed_config_loads() {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs"));
    let mut loaded = 0;
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            TrainConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
            loaded += 1;
        }
    }
    assert!(loaded >= 5, "{loaded} configs in {}", dir.display());
}

#[test]
fn typos_and_bad_values_are_named() {
    let e = TrainConfig::from_toml("[ppo]\nlearning_rat = 1.0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("learning_rat"), "{e}");
    let e = TrainConfig::from_toml("[run]\nscene_kind = \"maze\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("run.scene_kind"), "{e}");
    let e = TrainConfig::from_toml("[curriculum]\nsecondary_init_temperature = 0.0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("curriculum.secondary_init_temperature"), "{e}");
    let e = TrainConfig::from_toml("[run]\nstart_stage = 1.5\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("run.start_stage"), "{e}");
    let e = TrainConfig::from_toml("[curriculum]\nstart_stage_behaviours = [\"straight\"]\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("curriculum.start_stage_behaviours"), "{e}");
    let budgets = "[curriculum.secondary_env_steps_by_behaviour]\n";
    let c = TrainConfig::from_toml(&format!("{budgets}lift = 5000\n")).unwrap();
    assert_eq!(c.curriculum.secondary_env_steps_by_behaviour["lift"], 5000);
    let e = TrainConfig::from_toml(&format!("{budgets}hover = 5000\n"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("secondary_env_steps_by_behaviour"), "{e}");
    let e = TrainConfig::from_toml("[run]\ninvalid_reward = 0.5\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("run.invalid_reward"), "{e}");
    let e = TrainConfig::from_toml("[curriculum]\nreplay_imitation_coef = -1.0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("curriculum.replay_imitation_coef"), "{e}");
    let e = TrainConfig::from_toml("[curriculum]\nreplay_balance = \"kind\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("replay_balance"), "{e}");
    let e = TrainConfig::from_toml("[ppo]\nconv_kernel = \"cudnn\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("ppo.conv_kernel") && e.contains("native"), "{e}");
    let burn = TrainConfig::from_toml("[ppo]\nconv_kernel = \"burn\"\n").unwrap();
    assert_eq!(burn.ppo.conv_kernel, "burn");
}

#[test]
fn a_resume_may_extend_the_budget_or_retune_the_curriculum_but_not_ppo() {
    let stored = TrainConfig::default().to_toml();
    let changes = |c: &TrainConfig, keys: &[&str]| c.changes_from_stored(&stored, keys).unwrap();
    let mut longer = TrainConfig::default();
    longer.run.total_env_steps *= 2;
    assert!(changes(&longer, &[]).is_empty());
    longer.run.failure_resample_probability = 0.3;
    longer.run.failure_memory_per_env = 4;
    assert!(changes(&longer, &[]).is_empty());
    let mut retuned = TrainConfig::default();
    retuned.curriculum.secondary_init_temperature = 10.0;
    assert!(changes(&retuned, &[]).is_empty());
    retuned.curriculum.replay_imitation_coef = 0.5;
    assert!(changes(&retuned, &["secondary_env_steps"]).is_empty());
    assert_eq!(
        changes(&retuned, &["replay_imitation_coef"]),
        ["curriculum.replay_imitation_coef: 0.0 -> 0.5"],
        "a stage that reads a curriculum key keeps it"
    );
    let mut other = TrainConfig::default();
    other.ppo.entropy_coef *= 2.0;
    other.run.num_envs += 1;
    let found = changes(&other, &[]);
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(found[0].starts_with("ppo.entropy_coef: "), "{found:?}");
    assert!(found[1].starts_with("run.num_envs: "), "{found:?}");
    // A config stored before the start-stage keys existed means the curriculum off.
    let old = stored
        .lines()
        .filter(|l| !l.starts_with("start_stage"))
        .collect::<Vec<_>>()
        .join("\n");
    assert!(old.len() < stored.len());
    assert!(TrainConfig::default()
        .changes_from_stored(&old, &[])
        .unwrap()
        .is_empty());
    let mut staged = TrainConfig::default();
    staged.run.start_stage = 0.0;
    assert!(!staged.changes_from_stored(&old, &[]).unwrap().is_empty());
    let e = TrainConfig::default()
        .changes_from_stored("[run\n", &[])
        .unwrap_err();
    assert!(matches!(e, ConfigError::Stored(_)), "{e}");
    assert!(e.to_string().contains("does not parse"));
}
