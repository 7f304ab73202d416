//! Domain randomization of stored trajectories (paper: "Domain Randomization"): new scenes with
//! the same start and target in which the same actions still succeed.
//!
//! For each source trajectory:
//! 1. Replay it; a source that does not reach the target is rejected (counted, with the reason).
//!    Its undone actions are dropped ([`Trajectory::without_undone_actions`]) so every remaining
//!    action is a real motion.
//! 2. Mark its essential area ([`EssentialArea`], margin [`RandomizeConfig::essential_margin_m`]).
//! 3. Keep the source's obstacles that meet the area, as they were; drop the others.
//! 4. For each new scene: draw a count in `new_obstacles_min..=new_obstacles_max`, then that many
//!    obstacles of any kind and yaw (0° or 90°) centred on distinct 0.25 m grid cells inside the
//!    arena (the box around start and target grown by the episode's `arena_margin_m`), each
//!    chosen among the placements whose footprint misses the essential area.
//! 5. Replay the actions in the new scene and keep it only if the episode succeeds at the last
//!    action with no undone action at all. By construction nothing can change, but the simulator
//!    is the judge, not the construction.
//!
//! Randomness: source `i` draws from ChaCha8 seeded with the batch seed, stream `i`. A source's
//! scenes therefore depend only on (seed, i, source), which makes the batch identical for the
//! same seed and lets a killed generation resume at any source.

use super::batch_file::{
    fnv1a, BatchFileError, BatchHeader, BatchWriter, Chunk, PackedObstacle, SourceRecord,
    TrajectoryBatch,
};
use wheelleg_robot::RobotDescription;
mod stats;

use super::sweep::{EssentialArea, DEFAULT_MARGIN_M};
use super::{ReplayError, Trajectory};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
pub use stats::{Progress, Stats};
use std::collections::HashSet;
use std::fmt;
use std::path::Path;
use wheelleg_sim::env::{EnvConfig, Status};
use wheelleg_sim::obstacle::{cell_centre_m, Obstacle, ObstacleKind, ObstacleYaw, GRID_CELL_M};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;

/// What to generate.
#[derive(Clone, Debug, PartialEq)]
pub struct RandomizeConfig {
    /// Scenes tried per source trajectory (the paper: 10^3).
    pub per_trajectory: usize,
    /// Seed of the randomization.
    pub seed: u64,
    /// Fewest new obstacles per scene.
    pub new_obstacles_min: u8,
    /// Most new obstacles per scene (fewer when the free cells run out).
    pub new_obstacles_max: u8,
    /// Margin of the essential area, m.
    pub essential_margin_m: f32,
    /// Also store each source in its own scene (the ablation "no randomization" uses only
    /// these: `per_trajectory = 0`).
    pub include_original: bool,
    /// Episode rules of the replays, on the robot's geometry.
    pub env: EnvConfig,
    /// The robot the trajectories were driven by (its geometry is `env`'s), named in the
    /// batch's header.
    pub robot: RobotDescription,
    /// A chunk is written (and synced) once it holds at least this many scenes: the work a
    /// killed generation can lose.
    pub chunk_scenes: usize,
}

impl Default for RandomizeConfig {
    fn default() -> Self {
        RandomizeConfig {
            per_trajectory: 1000,
            seed: 0,
            // The complex scenes' 1 to 8 (sim::generate), so randomized scenes look like them.
            new_obstacles_min: 1,
            new_obstacles_max: 8,
            essential_margin_m: DEFAULT_MARGIN_M,
            include_original: true,
            env: EnvConfig::default(),
            robot: RobotDescription::shipped(),
            chunk_scenes: 4096,
        }
    }
}

impl RandomizeConfig {
    /// The file header of a batch of `sources` made with this configuration.
    pub fn header(&self, sources: &[Trajectory]) -> Result<BatchHeader, BatchFileError> {
        if self.new_obstacles_min > self.new_obstacles_max {
            return Err(BatchFileError::Unstorable {
                reason: format!(
                    "new_obstacles_min {} > new_obstacles_max {}",
                    self.new_obstacles_min, self.new_obstacles_max
                ),
            });
        }
        let per_trajectory =
            u32::try_from(self.per_trajectory).map_err(|_| BatchFileError::Unstorable {
                reason: format!("per_trajectory {} too large", self.per_trajectory),
            })?;
        if !(self.essential_margin_m.is_finite() && self.essential_margin_m >= 0.0) {
            return Err(BatchFileError::Unstorable {
                reason: format!(
                    "essential_margin_m must be a finite number >= 0, got {}",
                    self.essential_margin_m
                ),
            });
        }
        let simulated = SimulatedRobot::of(&self.robot)
            .map_err(|reason| BatchFileError::Unstorable { reason })?;
        if self.env.robot != simulated {
            return Err(BatchFileError::Unstorable {
                reason: format!(
                    "the replays' geometry or lattice is not robot '{}''s",
                    self.robot.name
                ),
            });
        }
        Ok(BatchHeader {
            robot: (self.robot != RobotDescription::shipped()).then(|| self.robot.clone()),
            seed: self.seed,
            per_trajectory,
            sources: sources.len() as u64,
            sources_fingerprint: fingerprint(sources),
            new_obstacles_min: self.new_obstacles_min,
            new_obstacles_max: self.new_obstacles_max,
            essential_margin_m: self.essential_margin_m,
            include_original: self.include_original,
            max_steps: self.env.max_steps,
            success_radius_m: self.env.success_radius_m,
            give_up_margin_m: self.env.give_up_margin_m,
            arena_margin_m: self.env.arena_margin_m,
        })
    }
}

/// FNV-1a over every source's scene and actions, in order.
fn fingerprint(sources: &[Trajectory]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for t in sources {
        let s = &t.scenario;
        h = fnv1a(s.name.as_bytes(), h);
        h = fnv1a(&[super::behaviour_code(t.behaviour)], h);
        for v in [
            s.start.position.x,
            s.start.position.y,
            s.target.x,
            s.target.y,
        ] {
            h = fnv1a(&v.to_le_bytes(), h);
        }
        for v in [
            s.start.yaw_steps,
            s.start.clearance_steps,
            s.start.track_steps,
        ] {
            h = fnv1a(&v.to_le_bytes(), h);
        }
        for o in &s.obstacles {
            h = fnv1a(&[o.kind as u8, o.yaw as u8], h);
            h = fnv1a(&o.centre.x.to_le_bytes(), h);
            h = fnv1a(&o.centre.y.to_le_bytes(), h);
        }
        h = fnv1a(&(t.actions.len() as u64).to_le_bytes(), h);
        let actions: Vec<u8> = t.actions.iter().map(|a| a.index() as u8).collect();
        h = fnv1a(&actions, h);
    }
    h
}

/// A source made ready for randomization.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// The source without undone actions, its obstacles as stored.
    pub source: Trajectory,
    /// Its essential area.
    pub area: EssentialArea,
    /// Its obstacles that meet the area (in every scene).
    pub kept: Vec<PackedObstacle>,
    /// Its other obstacles (its own scene's, dropped from new scenes).
    pub dropped: Vec<PackedObstacle>,
    /// Every placement of a new obstacle allowed: in the arena, missing the area, not on a
    /// kept obstacle's cell.
    pub placements: Vec<PackedObstacle>,
}

/// Why a source cannot be randomized; its text is the reason the source's record stores.
#[derive(Clone, Debug, PartialEq)]
pub enum Unusable {
    /// It does not replay (with or without its undone actions), or its essential area cannot
    /// be marked.
    Replay(ReplayError),
    /// Its replay ends elsewhere than at the target.
    Missed(Status),
    /// An obstacle is not centred on a grid cell, so the file cannot store it.
    OffGrid {
        /// The obstacle's index in the scene.
        index: usize,
        /// Its centre, metres.
        x: f32,
        /// See `x`.
        y: f32,
    },
    /// Without its undone actions it no longer succeeds, or some action becomes invalid.
    UndoneActions,
}

impl fmt::Display for Unusable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unusable::Replay(e) => write!(f, "{e}"),
            Unusable::Missed(status) => write!(f, "does not reach the target ({status:?})"),
            Unusable::OffGrid { index, x, y } => write!(
                f,
                "obstacle {index} at ({x}, {y}) is not on a 0.25 m grid-cell centre"
            ),
            Unusable::UndoneActions => f.write_str("does not replay without its undone actions"),
        }
    }
}

impl std::error::Error for Unusable {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Unusable::Replay(e) => Some(e),
            _ => None,
        }
    }
}

impl From<ReplayError> for Unusable {
    fn from(e: ReplayError) -> Self {
        Unusable::Replay(e)
    }
}

/// Checks a source and computes what randomizing it needs; `Err` says why it cannot be used.
pub fn prepare(trajectory: &Trajectory, config: &RandomizeConfig) -> Result<Prepared, Unusable> {
    let replay = trajectory.replay(config.env)?;
    if !replay.success() {
        return Err(Unusable::Missed(replay.status));
    }
    let packed: Vec<PackedObstacle> = trajectory
        .scenario
        .obstacles
        .iter()
        .enumerate()
        .map(|(i, o)| {
            PackedObstacle::pack(o).ok_or(Unusable::OffGrid {
                index: i,
                x: o.centre.x,
                y: o.centre.y,
            })
        })
        .collect::<Result<_, _>>()?;
    let mut source = trajectory.without_undone_actions(config.env)?;
    // What is stored is what is replayed: obstacles exactly as they come back from the file.
    source.scenario.obstacles = packed.iter().filter_map(PackedObstacle::unpack).collect();
    let replay = source.replay(config.env)?;
    if !replay.success() || replay.invalid_actions > 0 {
        return Err(Unusable::UndoneActions);
    }
    let area = EssentialArea::of_trajectory(&source, config.env, config.essential_margin_m)?;
    let (kept, dropped): (Vec<PackedObstacle>, Vec<PackedObstacle>) = packed
        .iter()
        .partition(|p| p.unpack().is_some_and(|o| area.intersects_obstacle(&o)));
    let occupied: HashSet<(i16, i16)> = kept.iter().map(|p| (p.cell_x, p.cell_y)).collect();
    let s = &source.scenario;
    let margin = config.env.arena_margin_m;
    let (x0, x1) = (
        s.start.position.x.min(s.target.x) - margin,
        s.start.position.x.max(s.target.x) + margin,
    );
    let (y0, y1) = (
        s.start.position.y.min(s.target.y) - margin,
        s.start.position.y.max(s.target.y) + margin,
    );
    // Cells whose centre lies in the arena.
    let first = |lo: f32| (lo / GRID_CELL_M - 0.5).ceil() as i32;
    let last = |hi: f32| (hi / GRID_CELL_M - 0.5).floor() as i32;
    let mut placements = Vec::new();
    for cx in first(x0)..=last(x1) {
        for cy in first(y0)..=last(y1) {
            let (Ok(cell_x), Ok(cell_y)) = (i16::try_from(cx), i16::try_from(cy)) else {
                continue;
            };
            if occupied.contains(&(cell_x, cell_y)) {
                continue;
            }
            for kind in ObstacleKind::ALL {
                for yaw in [ObstacleYaw::Deg0, ObstacleYaw::Deg90] {
                    let o = Obstacle::new(kind, cell_centre_m(cx), cell_centre_m(cy), yaw);
                    if !area.intersects_obstacle(&o) {
                        if let Some(p) = PackedObstacle::pack(&o) {
                            placements.push(p);
                        }
                    }
                }
            }
        }
    }
    Ok(Prepared {
        source,
        area,
        kept,
        dropped,
        placements,
    })
}

/// Draws the new obstacles of one scene.
fn draw_scene(
    prepared: &Prepared,
    config: &RandomizeConfig,
    rng: &mut impl Rng,
) -> Vec<PackedObstacle> {
    let count = rng.random_range(config.new_obstacles_min..=config.new_obstacles_max) as usize;
    let mut cells: HashSet<(i16, i16)> = HashSet::with_capacity(count);
    let mut out = Vec::with_capacity(count);
    if prepared.placements.is_empty() {
        return out;
    }
    // Rejection of taken cells; the bound only matters when free cells run out.
    let mut attempts = 0;
    while out.len() < count && attempts < 20 * count {
        attempts += 1;
        let p = prepared.placements[rng.random_range(0..prepared.placements.len())];
        if cells.insert((p.cell_x, p.cell_y)) {
            out.push(p);
        }
    }
    out
}

/// Whether `actions` replay in `scenario` to success at the last action with every action
/// valid.
fn replays_clean(source: &Trajectory, obstacles: Vec<Obstacle>, env: EnvConfig) -> bool {
    let candidate = Trajectory {
        scenario: Scenario {
            name: String::new(),
            start: source.scenario.start,
            target: source.scenario.target,
            obstacles,
        },
        actions: source.actions.clone(),
        behaviour: source.behaviour,
    };
    candidate
        .replay(env)
        .is_ok_and(|r| r.status == Status::Success && r.invalid_actions == 0 && r.collisions == 0)
}

/// Randomizes source `index` into its stored record (scenes kept, counts, or the reason it was
/// rejected).
pub fn randomize_source(
    trajectory: &Trajectory,
    index: u64,
    config: &RandomizeConfig,
) -> Result<SourceRecord, BatchFileError> {
    let mut record = SourceRecord::of_trajectory(trajectory)
        .map_err(|e| BatchFileError::Unstorable { reason: e.0 })?;
    let prepared = match prepare(trajectory, config) {
        Ok(p) => p,
        Err(reason) => {
            record.rejected = reason.to_string();
            record.actions.clear();
            return Ok(record);
        }
    };
    record.actions = prepared
        .source
        .actions
        .iter()
        .map(|a| a.index() as u8)
        .collect();
    record.kept = prepared.kept.clone();
    let kept: Vec<Obstacle> = prepared
        .kept
        .iter()
        .filter_map(PackedObstacle::unpack)
        .collect();
    let with_kept = |new: &[PackedObstacle]| {
        let mut all = kept.clone();
        all.extend(new.iter().filter_map(PackedObstacle::unpack));
        all
    };
    if config.include_original
        && replays_clean(&prepared.source, with_kept(&prepared.dropped), config.env)
    {
        record.original_included = true;
        record.scenes.push(prepared.dropped.clone());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    rng.set_stream(index);
    for _ in 0..config.per_trajectory {
        let new = draw_scene(&prepared, config, &mut rng);
        record.tried += 1;
        if replays_clean(&prepared.source, with_kept(&new), config.env) {
            record.scenes.push(new);
        }
    }
    Ok(record)
}

/// [`randomize_batch_with`] with the default configuration, `per_trajectory` scenes per source
/// and `seed`.
pub fn randomize_batch(
    trajectories: &[Trajectory],
    per_trajectory: usize,
    seed: u64,
    out: &Path,
    progress: impl FnMut(Progress),
) -> Result<Stats, BatchFileError> {
    let config = RandomizeConfig {
        per_trajectory,
        seed,
        ..RandomizeConfig::default()
    };
    randomize_batch_with(trajectories, &config, out, progress)
}

/// Randomizes every trajectory and writes the batch file `out` (via `<out>.partial`, resumed if
/// it exists; see [`super::batch_file`]). When `out` already holds a complete batch with the
/// same header, nothing is generated and its statistics are returned; one with another header
/// is refused.
pub fn randomize_batch_with(
    trajectories: &[Trajectory],
    config: &RandomizeConfig,
    out: &Path,
    mut progress: impl FnMut(Progress),
) -> Result<Stats, BatchFileError> {
    let header = config.header(trajectories)?;
    if out.exists() {
        let bytes = std::fs::read(out).map_err(|e| BatchFileError::Io {
            path: out.to_path_buf(),
            message: e.to_string(),
        })?;
        let (found, start) = super::batch_file::parse_header(&bytes)?;
        if let Some((field, in_file, requested)) = found.first_difference(&header) {
            return Err(BatchFileError::Mismatch {
                field,
                in_file: format!("{in_file} (in {})", out.display()),
                requested,
            });
        }
        // Loading checks every chunk; then count from the records.
        TrajectoryBatch::from_bytes(&bytes)?;
        let scan = super::batch_file::scan_chunks(&bytes, &found, start);
        let mut stats = Stats {
            resumed_at_source: found.sources,
            file_bytes: bytes.len() as u64,
            ..Stats::default()
        };
        for chunk in &scan.chunks {
            for (i, r) in chunk.sources.iter().enumerate() {
                stats.count(chunk.first_source + i as u64, r);
            }
        }
        return Ok(stats);
    }
    let (mut writer, resume) = BatchWriter::resume(out, &header)?;
    let mut stats = Stats {
        resumed_at_source: resume.next_source,
        discarded_tail_bytes: resume.discarded_tail_bytes,
        ..Stats::default()
    };
    for chunk in &resume.chunks {
        for (i, r) in chunk.sources.iter().enumerate() {
            stats.count(chunk.first_source + i as u64, r);
        }
    }
    let mut pending = Chunk {
        first_source: resume.next_source,
        sources: Vec::new(),
    };
    let mut pending_scenes = 0;
    for index in resume.next_source..trajectories.len() as u64 {
        let record = randomize_source(&trajectories[index as usize], index, config)?;
        stats.count(index, &record);
        pending_scenes += record.scenes.len();
        pending.sources.push(record);
        if pending_scenes >= config.chunk_scenes {
            writer.append(&pending)?;
            pending = Chunk {
                first_source: index + 1,
                sources: Vec::new(),
            };
            pending_scenes = 0;
        }
        progress(Progress {
            sources_done: index + 1,
            sources_total: trajectories.len() as u64,
            tried: stats.tried,
            kept: stats.trajectories(),
        });
    }
    if !pending.sources.is_empty() {
        writer.append(&pending)?;
    }
    stats.file_bytes = writer.bytes();
    writer.finish(out)?;
    Ok(stats)
}
