//! The randomized batch and its file: determinism, damaged files, resumed generation.

use super::*;

#[test]
fn the_same_seed_gives_the_same_batch() {
    let dir = scratch("seed");
    let sources = sources();
    let run = |name: &str, seed: u64| {
        let out = dir.join(name);
        randomize_batch(&sources, 20, seed, &out, |_| {}).unwrap();
        std::fs::read(out).unwrap()
    };
    let a = run("a.wltb", 7);
    assert_eq!(a, run("b.wltb", 7));
    assert_ne!(a, run("c.wltb", 8));
}

fn small_chunks() -> RandomizeConfig {
    RandomizeConfig {
        per_trajectory: 12,
        seed: 3,
        chunk_scenes: 1,
        ..RandomizeConfig::default()
    }
}

#[test]
fn damaged_or_foreign_files_are_refused_with_a_typed_error() {
    let dir = scratch("damage");
    let out = dir.join("batch.wltb");
    randomize_batch_with(&sources(), &small_chunks(), &out, |_| {}).unwrap();
    let good = std::fs::read(&out).unwrap();
    assert!(TrajectoryBatch::from_bytes(&good).is_ok());

    let mut magic = good.clone();
    magic[0] = b'X';
    assert!(matches!(
        TrajectoryBatch::from_bytes(&magic),
        Err(BatchFileError::BadMagic { .. })
    ));
    assert!(matches!(
        TrajectoryBatch::from_bytes(b"{\"scenarios\":[]}"),
        Err(BatchFileError::BadMagic { .. })
    ));

    let mut version = good.clone();
    version[8] = 2;
    let e = TrajectoryBatch::from_bytes(&version).unwrap_err();
    assert!(
        matches!(
            e,
            BatchFileError::UnsupportedVersion {
                found: 2,
                supported: 1
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("version 2"), "{e}");

    let mut header = good.clone();
    header[PREAMBLE_LEN + 1] ^= 0x40;
    assert!(matches!(
        TrajectoryBatch::from_bytes(&header),
        Err(BatchFileError::HeaderCorrupt { .. })
    ));

    let mut body = good.clone();
    let at = good.len() - 5;
    body[at] ^= 0x01;
    let e = TrajectoryBatch::from_bytes(&body).unwrap_err();
    assert!(matches!(e, BatchFileError::ChunkCorrupt { .. }), "{e}");
    assert!(e.to_string().contains("CRC-32"), "{e}");

    let e = TrajectoryBatch::from_bytes(&good[..good.len() - 3]).unwrap_err();
    assert!(matches!(e, BatchFileError::Truncated { .. }), "{e}");
    assert!(e.to_string().contains("truncated"), "{e}");

    // Never a panic, whatever the damage: every prefix, and a flipped bit in every byte.
    for len in 0..good.len() {
        assert!(
            TrajectoryBatch::from_bytes(&good[..len]).is_err(),
            "prefix {len}"
        );
    }
    for at in 0..good.len() {
        let mut bad = good.clone();
        bad[at] ^= 0x10;
        assert!(TrajectoryBatch::from_bytes(&bad).is_err(), "flip at {at}");
    }
    assert_eq!(&good[..8], &MAGIC);
}

#[test]
fn a_killed_generation_resumes_from_its_last_complete_chunk() {
    let dir = scratch("resume");
    let sources = sources();
    let config = small_chunks();
    let whole = dir.join("whole.wltb");
    let full = randomize_batch_with(&sources, &config, &whole, |_| {}).unwrap();
    let good = std::fs::read(&whole).unwrap();

    // Cut the file inside its last chunk and inside its second: as if killed while writing.
    let (_, first_chunk) = wheelleg_trainer::trajectory::batch_file::parse_header(&good).unwrap();
    for cut in [good.len() - 7, first_chunk + 5, first_chunk + 30] {
        let out = dir.join(format!("cut-{cut}.wltb"));
        std::fs::write(partial_path(&out), &good[..cut]).unwrap();
        let loaded = TrajectoryBatch::from_bytes(&good[..cut]);
        assert!(loaded.is_err(), "a cut file does not load");
        let stats = randomize_batch_with(&sources, &config, &out, |_| {}).unwrap();
        assert!(
            stats.discarded_tail_bytes > 0,
            "cut {cut}: the half chunk is dropped"
        );
        assert_eq!(
            std::fs::read(&out).unwrap(),
            good,
            "cut {cut}: same bytes as unbroken"
        );
        assert_eq!(stats.trajectories(), full.trajectories());
        assert_eq!(stats.tried, full.tried);
    }

    // A partial file of other parameters is not continued.
    let out = dir.join("other.wltb");
    std::fs::write(partial_path(&out), &good[..good.len() - 7]).unwrap();
    let other = RandomizeConfig {
        seed: 4,
        ..config.clone()
    };
    let e = randomize_batch_with(&sources, &other, &out, |_| {}).unwrap_err();
    assert!(
        matches!(e, BatchFileError::Mismatch { field: "seed", .. }),
        "{e}"
    );
}

#[test]
fn an_incomplete_batch_is_refused() {
    let dir = scratch("incomplete");
    let out = dir.join("batch.wltb");
    let sources = sources();
    randomize_batch_with(&sources[..2], &small_chunks(), &out, |_| {}).unwrap();
    // The same chunks under a header that promises three sources.
    let two = std::fs::read(&out).unwrap();
    let header = small_chunks().header(&sources).unwrap();
    let mut bytes = wheelleg_trainer::trajectory::batch_file::header_bytes(&header).unwrap();
    let (_, start) = wheelleg_trainer::trajectory::batch_file::parse_header(&two).unwrap();
    bytes.extend_from_slice(&two[start..]);
    let e = TrajectoryBatch::from_bytes(&bytes).unwrap_err();
    assert!(
        matches!(
            e,
            BatchFileError::Incomplete {
                sources_done: 2,
                sources_total: 3
            }
        ),
        "{e}"
    );
}

#[test]
fn a_failed_or_off_grid_source_is_rejected_and_counted() {
    let dir = scratch("reject");
    let mut failing = sources()[0].clone();
    failing.actions.truncate(2);
    let mut off_grid = sources()[2].clone();
    let far = off_grid.scenario.target + nalgebra::Vector2::new(0.0, 0.5);
    off_grid.scenario.obstacles.push(Obstacle::new(
        ObstacleKind::Bar,
        far.x + 0.01,
        far.y,
        ObstacleYaw::Deg0,
    ));
    let out = dir.join("batch.wltb");
    let stats = randomize_batch(&[failing, off_grid], 5, 1, &out, |_| {}).unwrap();
    assert_eq!(stats.sources_rejected, 2);
    assert!(
        stats.rejections[0].1.contains("does not reach"),
        "{:?}",
        stats.rejections
    );
    assert!(
        stats.rejections[1].1.contains("grid"),
        "{:?}",
        stats.rejections
    );
    assert_eq!(TrajectoryBatch::load(&out).unwrap().len(), 0);
}

#[test]
fn a_batch_names_its_robot_and_is_refused_for_another() {
    use wheelleg_robot::RobotDescription;
    use wheelleg_trainer::trajectory::batch_file::{header_bytes, parse_header};
    let strider = RobotDescription::load(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../robots/strider.toml"),
    )
    .unwrap();
    let shipped_header = small_chunks().header(&sources()).unwrap();
    // The shipped robot's header holds no robot record: its bytes are as before robots.
    let shipped_bytes = header_bytes(&shipped_header).unwrap();
    let header = wheelleg_trainer::trajectory::batch_file::BatchHeader {
        robot: Some(strider.clone()),
        ..shipped_header.clone()
    };
    let bytes = header_bytes(&header).unwrap();
    assert!(bytes.len() > shipped_bytes.len());
    let (back, _) = parse_header(&bytes).unwrap();
    assert_eq!(back, header);
    assert_eq!(
        *back.env_config().unwrap().robot.geometry(),
        strider.robot.geometry
    );
    assert!(back.check_robot(&strider, "batch.wltb").is_ok());
    let err = back
        .check_robot(&RobotDescription::shipped(), "batch.wltb")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("robot 'strider'") && err.contains("robot 'wheelleg'"),
        "{err}"
    );
    let err = parse_header(&shipped_bytes)
        .unwrap()
        .0
        .check_robot(&strider, "batch.wltb")
        .unwrap_err();
    assert!(
        matches!(
            err,
            wheelleg_trainer::TrainError::BatchRobot { part: "name", .. }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("the name differs"), "{err}");
}
