use super::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn sample() -> Checkpoint {
    let net = crate::network::init_policy(
        &Architecture::default_policy(),
        &mut ChaCha8Rng::seed_from_u64(1),
    );
    Checkpoint {
        kind: "baseline".into(),
        config_toml: "x".into(),
        seed: 3,
        iteration: 7,
        env_steps: 70_000,
        adam: Adam::new(&net),
        network: NetworkRecord::from_network(&net),
        sampler_word_pos: 12345,
        envs: vec![],
        elapsed_s: 1.5,
    }
}

#[test]
fn round_trips_and_refuses_damage() {
    let c = sample();
    let bytes = c.to_bytes().unwrap();
    assert_eq!(Checkpoint::from_bytes(&bytes).unwrap(), c);
    assert_eq!(
        c.network.to_network().unwrap(),
        crate::network::init_policy(
            &Architecture::default_policy(),
            &mut ChaCha8Rng::seed_from_u64(1)
        )
    );
    let e = Checkpoint::from_bytes(&bytes[..bytes.len() - 10]).unwrap_err();
    assert!(
        matches!(e, CheckpointError::Truncated { .. }) && e.to_string().contains("truncated"),
        "{e}"
    );
    let mut bad = bytes.clone();
    bad[100] ^= 1;
    let e = Checkpoint::from_bytes(&bad).unwrap_err();
    assert!(matches!(e, CheckpointError::Checksum), "{e}");
    assert!(e.to_string().contains("checksum"));
    let e = Checkpoint::from_bytes(b"hello world, this is not it").unwrap_err();
    assert!(matches!(e, CheckpointError::NotACheckpoint), "{e}");
    assert!(e.to_string().contains("magic"));
}

#[test]
fn extras_round_trip_and_empty_ones_leave_the_file_as_it_was() {
    let c = sample();
    let plain = c.to_bytes().unwrap();
    assert_eq!(
        c.to_bytes_with(&CheckpointExtras::default()).unwrap(),
        plain
    );
    let (back, extras) = Checkpoint::from_bytes_with_extras(&plain).unwrap();
    assert_eq!((back, extras), (c.clone(), CheckpointExtras::default()));
    let extras = CheckpointExtras {
        start_stage: Some(StartStageState {
            stage: 0.3,
            window: vec![(4, 10), (7, 9)],
            env_stages: vec![0.2, 0.3],
        }),
        failures: Some(vec!["{\"scenarios\": []}".into(), String::new()]),
        robot: None,
    };
    let bytes = c.to_bytes_with(&extras).unwrap();
    assert!(bytes.len() > plain.len());
    assert_eq!(
        Checkpoint::from_bytes_with_extras(&bytes).unwrap(),
        (c.clone(), extras)
    );
    assert_eq!(Checkpoint::from_bytes(&bytes).unwrap(), c);
    // Junk after the extras is refused, not ignored.
    let mut payload = bytes[HEADER_LEN..].to_vec();
    payload.push(0);
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    file.extend_from_slice(&fnv1a(&payload).to_le_bytes());
    file.extend_from_slice(&payload);
    let e = Checkpoint::from_bytes_with_extras(&file).unwrap_err();
    assert!(e.to_string().contains("after the extras"), "{e}");
}

#[test]
fn extras_written_before_the_failure_memory_still_load() {
    let c = sample();
    let start_stage = StartStageState {
        stage: 0.5,
        window: vec![(1, 2)],
        env_stages: vec![0.5],
    };
    // The older record: a struct of the start stage alone, encoded as that field.
    let mut payload = postcard::to_allocvec(&c).unwrap();
    payload.extend(postcard::to_allocvec(&Some(start_stage.clone())).unwrap());
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    file.extend_from_slice(&fnv1a(&payload).to_le_bytes());
    file.extend_from_slice(&payload);
    let (back, extras) = Checkpoint::from_bytes_with_extras(&file).unwrap();
    assert_eq!(back, c);
    assert_eq!(extras.start_stage, Some(start_stage));
    assert_eq!(extras.failures, None);
}

/// Regression (fuzz target `checkpoint_payload`): a stored architecture whose feature count
/// overflows `usize` panicked with a multiply overflow instead of being refused.
#[test]
fn impossible_architectures_are_refused() {
    let mut c = sample();
    c.network.arch.convs.clear();
    c.network.arch.height = (usize::MAX / 2, 3);
    let e = c.network.to_network().unwrap_err();
    assert!(e.to_string().contains("impossible"), "{e}");
    let mut c = sample();
    c.network.arch.convs[0].3 = 0;
    assert!(c
        .network
        .to_network()
        .unwrap_err()
        .to_string()
        .contains("stride"));
    let mut c = sample();
    c.network.arch.convs[1].0 = 7;
    assert!(c
        .network
        .to_network()
        .unwrap_err()
        .to_string()
        .contains("channels"));
    // The artifact itself, as the payload behind a valid header.
    let payload: [u8; 55] = [
        0, 0, 0, 0, 0, 133, 133, 133, 133, 133, 48, 133, 133, 133, 133, 133, 133, 133, 0, 35, 0, 0,
        0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 144, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1, 0,
        0, 0, 0,
    ];
    let mut file = MAGIC.to_vec();
    file.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    file.extend_from_slice(&fnv1a(&payload).to_le_bytes());
    file.extend_from_slice(&payload);
    assert!(Checkpoint::from_bytes(&file).is_err());
}

#[test]
fn mismatched_tensors_are_named() {
    let mut c = sample();
    c.network.tensors[2].pop();
    let e = c.network.to_network().unwrap_err();
    assert!(e.to_string().contains("conv1.weight"), "{e}");
}
