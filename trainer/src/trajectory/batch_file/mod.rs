//! The trajectory batch file and its in-memory form.
//!
//! Layout (all integers little-endian; docs/curriculum.md has the full specification):
//!
//! ```text
//! file   = magic "WLTRAJB\0" (8 bytes) | version u32 | header_len u32 | header_crc u32
//!          | header (postcard BatchHeader, header_len bytes) | chunk*
//! chunk  = payload_len u32 | payload_crc u32 | payload (postcard Chunk, payload_len bytes)
//! ```
//!
//! CRCs are CRC-32 (IEEE 802.3, the zlib/PNG one) of the bytes they follow. A chunk holds every
//! randomized scene of a run of consecutive source trajectories; the scenes of one source share
//! its start, target, actions and kept (essential) obstacles, which are stored once, so a scene
//! costs only its new obstacles (3 bytes each).
//!
//! Writing: the header is written atomically (temporary file, fsync, rename) as
//! `<out>.partial`, chunks are appended and fsync'ed one at a time, and the finished file is
//! renamed to `<out>`. So `<out>` is only ever a complete batch; a killed generation leaves
//! `<out>.partial`, whose tail may be half a chunk.
//!
//! Reading ([`TrajectoryBatch::load`]) is strict: a wrong magic or version, a CRC mismatch, a
//! truncated chunk or a batch that does not cover all its sources is refused with a
//! [`BatchFileError`] naming it. Resuming ([`BatchWriter::resume`]) instead cuts a partial
//! file back to its last valid chunk and goes on from there: generation is deterministic per
//! source, so nothing is lost.

use super::{behaviour_code, behaviour_of_code, Trajectory};
use crate::error::TrainError;
use core::fmt;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::action::{Action, ActionLattice, COUNT};
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::generate::Behaviour;
use wheelleg_sim::obstacle::{cell_centre_m, Obstacle, ObstacleKind, ObstacleYaw, GRID_CELL_M};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

mod bytes;
mod in_memory;
mod writer;

pub use bytes::{chunk_bytes, header_bytes, parse_header, scan_chunks, ChunkScan};
pub use in_memory::{StoredSource, TrajectoryBatch};
pub use writer::{partial_path, BatchWriter, ResumePoint};

/// First 8 bytes of every batch file.
pub const MAGIC: [u8; 8] = *b"WLTRAJB\0";
/// The format version this code reads and writes.
pub const VERSION: u32 = 1;
/// Bytes before the header payload: magic, version, header length, header CRC.
pub const PREAMBLE_LEN: usize = 8 + 4 + 4 + 4;
/// Bytes before a chunk payload: length and CRC.
pub const CHUNK_PREFIX_LEN: usize = 4 + 4;
/// Largest chunk payload accepted: a length beyond it is damage, not data.
pub const MAX_CHUNK_BYTES: usize = 256 << 20;
/// Largest header payload accepted.
const MAX_HEADER_BYTES: usize = 1 << 16;

/// CRC-32 (IEEE 802.3 polynomial, reflected, as zlib and PNG compute it): the runtime's, so the
/// weights file and the batch file share one implementation.
pub use wheelleg_runtime::model::crc32::crc32;

/// FNV-1a, 64 bit: the fingerprint of the source trajectories (not a checksum of the file).
pub(crate) fn fnv1a(bytes: &[u8], seed: u64) -> u64 {
    bytes
        .iter()
        .fold(seed, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// Everything that decides a batch's content: a resume with other values is refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BatchHeader {
    /// Seed of the randomization (ChaCha8, one stream per source).
    pub seed: u64,
    /// Scenes tried per source trajectory.
    pub per_trajectory: u32,
    /// Number of source trajectories.
    pub sources: u64,
    /// FNV-1a of the encoded source trajectories: the same sources in the same order.
    pub sources_fingerprint: u64,
    /// Fewest new obstacles per scene.
    pub new_obstacles_min: u8,
    /// Most new obstacles per scene.
    pub new_obstacles_max: u8,
    /// Margin of the essential area, m.
    pub essential_margin_m: f32,
    /// Whether each source's own (original) scene is stored as its first scene.
    pub include_original: bool,
    /// Episode rules the replays were checked under (and must be replayed under).
    pub max_steps: u32,
    /// Episode rule: success radius, m.
    pub success_radius_m: f32,
    /// Episode rule: give-up margin, m.
    pub give_up_margin_m: f32,
    /// Episode rule: arena margin, m.
    pub arena_margin_m: f32,
    /// The robot the trajectories were driven by; `None` for the shipped robot. Stored after
    /// the other fields, as the description's TOML, only when present: a shipped robot's
    /// header is byte for byte what it was before robots were named.
    #[serde(skip)]
    pub robot: Option<RobotDescription>,
}

impl BatchHeader {
    /// The robot the trajectories were driven by.
    pub fn robot(&self) -> RobotDescription {
        self.robot.clone().unwrap_or_default()
    }

    /// Refuses a batch made for another robot than `robot`, naming both.
    pub fn check_robot(&self, robot: &RobotDescription, what: &str) -> Result<(), TrainError> {
        let made = self.robot();
        match robot.difference(&made.trained_for()) {
            None => Ok(()),
            Some(part) => Err(TrainError::BatchRobot {
                what: what.to_string(),
                batch_robot: made.name.clone(),
                run_robot: robot.name.clone(),
                part,
            }),
        }
    }

    /// The batch's robot as the simulator steps it; refused, as a damaged header, when the
    /// simulator cannot step on its lattice.
    pub fn simulated_robot(&self) -> Result<SimulatedRobot, BatchFileError> {
        SimulatedRobot::of(&self.robot()).map_err(|e| BatchFileError::HeaderCorrupt {
            reason: format!("robot: {e}"),
        })
    }

    /// The episode rules of the batch, on its robot.
    pub fn env_config(&self) -> Result<EnvConfig, BatchFileError> {
        Ok(EnvConfig {
            robot: self.simulated_robot()?,
            max_steps: self.max_steps,
            success_radius_m: self.success_radius_m,
            give_up_margin_m: self.give_up_margin_m,
            arena_margin_m: self.arena_margin_m,
            // Not stored: a stored trajectory has no undone action, so it is never paid.
            ..EnvConfig::default()
        })
    }

    /// The first field that differs from `other`, with both values.
    pub fn first_difference(&self, other: &BatchHeader) -> Option<(&'static str, String, String)> {
        macro_rules! check {
            ($($field:ident),*) => {
                $(if self.$field != other.$field {
                    return Some((
                        stringify!($field),
                        format!("{:?}", self.$field),
                        format!("{:?}", other.$field),
                    ));
                })*
            };
        }
        check!(
            seed,
            per_trajectory,
            sources,
            sources_fingerprint,
            new_obstacles_min,
            new_obstacles_max,
            essential_margin_m,
            include_original,
            max_steps,
            success_radius_m,
            give_up_margin_m,
            arena_margin_m
        );
        if self.robot != other.robot {
            let name = |r: &BatchHeader| r.robot().name;
            return Some(("robot", name(self), name(other)));
        }
        None
    }
}

/// An obstacle on the 0.25 m grid in 6 bytes of memory and typically 3 on disk (postcard
/// varints): `code` = kind index ([`ObstacleKind::ALL`]) * 2 + yaw (0: 0°, 1: 90°), and the
/// cell indices (centre = (index + 0.5) * 0.25 m).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct PackedObstacle {
    /// Kind and yaw.
    pub code: u8,
    /// Cell index along world x.
    pub cell_x: i16,
    /// Cell index along world y.
    pub cell_y: i16,
}

/// Cell index of a grid-cell centre coordinate, if it is one.
fn cell_index_of(value_m: f32) -> Option<i16> {
    let index = (value_m / GRID_CELL_M - 0.5).round();
    if !(i16::MIN as f32..=i16::MAX as f32).contains(&index) {
        return None;
    }
    (cell_centre_m(index as i32) == value_m).then_some(index as i16)
}

impl PackedObstacle {
    /// Packs an obstacle; `None` when its centre is not exactly a grid-cell centre.
    pub fn pack(obstacle: &Obstacle) -> Option<PackedObstacle> {
        let kind = ObstacleKind::ALL.iter().position(|&k| k == obstacle.kind)? as u8;
        let yaw = match obstacle.yaw {
            ObstacleYaw::Deg0 => 0,
            ObstacleYaw::Deg90 => 1,
        };
        Some(PackedObstacle {
            code: kind * 2 + yaw,
            cell_x: cell_index_of(obstacle.centre.x)?,
            cell_y: cell_index_of(obstacle.centre.y)?,
        })
    }

    /// The obstacle; `None` for an unknown code.
    pub fn unpack(&self) -> Option<Obstacle> {
        let kind = *ObstacleKind::ALL.get((self.code / 2) as usize)?;
        let yaw = match self.code % 2 {
            0 => ObstacleYaw::Deg0,
            _ => ObstacleYaw::Deg90,
        };
        Some(Obstacle::new(
            kind,
            cell_centre_m(self.cell_x as i32),
            cell_centre_m(self.cell_y as i32),
            yaw,
        ))
    }
}

/// One source trajectory and its kept scenes, as stored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SourceRecord {
    /// The source scenario's name.
    pub name: String,
    /// The behaviour's code ([`behaviour_code`]).
    pub behaviour: u8,
    /// Start position x, m.
    pub start_x_m: f32,
    /// Start position y, m.
    pub start_y_m: f32,
    /// Start yaw in 5° steps.
    pub start_yaw_steps: u8,
    /// Start clearance in steps from the default.
    pub start_clearance_steps: i8,
    /// Start track in steps from the default.
    pub start_track_steps: i8,
    /// Target x, m.
    pub target_x_m: f32,
    /// Target y, m.
    pub target_y_m: f32,
    /// Joint action indices (0..243), undone actions already removed.
    pub actions: Vec<u8>,
    /// The source's obstacles inside the essential area: in every scene, as they were.
    pub kept: Vec<PackedObstacle>,
    /// Scenes tried for this source.
    pub tried: u32,
    /// Whether `scenes[0]` is the source's own scene (its obstacles outside the area).
    pub original_included: bool,
    /// Why the source was not randomized (empty when it was).
    pub rejected: String,
    /// The new obstacles of each kept scene.
    pub scenes: Vec<Vec<PackedObstacle>>,
}

/// What [`SourceRecord::start_state`] and friends refuse.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordError(pub String);

impl SourceRecord {
    /// The start state, its steps counted on `lattice` (the batch's robot's).
    pub fn start_state(&self, lattice: &ActionLattice) -> RobotState {
        RobotState {
            clearance_steps: self.start_clearance_steps as i32,
            track_steps: self.start_track_steps as i32,
            ..RobotState::new(
                Point2::new(self.start_x_m, self.start_y_m),
                self.start_yaw_steps as i32,
                lattice,
            )
        }
    }

    /// The record of a trajectory, with no scenes yet; an error (with the reason) when it cannot
    /// be stored compactly.
    pub fn of_trajectory(trajectory: &Trajectory) -> Result<SourceRecord, RecordError> {
        let s = &trajectory.scenario;
        let narrow = |v: i32, what: &str| {
            i8::try_from(v).map_err(|_| RecordError(format!("{what} steps {v} out of range")))
        };
        Ok(SourceRecord {
            name: s.name.clone(),
            behaviour: behaviour_code(trajectory.behaviour),
            start_x_m: s.start.position.x,
            start_y_m: s.start.position.y,
            start_yaw_steps: u8::try_from(
                s.start.yaw_steps.rem_euclid(s.start.yaw_steps_per_turn()),
            )
            .map_err(|_| RecordError(format!("yaw steps {} out of range", s.start.yaw_steps)))?,
            start_clearance_steps: narrow(s.start.clearance_steps, "clearance")?,
            start_track_steps: narrow(s.start.track_steps, "track")?,
            target_x_m: s.target.x,
            target_y_m: s.target.y,
            actions: trajectory.actions.iter().map(|a| a.index() as u8).collect(),
            kept: Vec::new(),
            tried: 0,
            original_included: false,
            rejected: String::new(),
            scenes: Vec::new(),
        })
    }
}

/// Every kept scene of a run of consecutive sources.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Chunk {
    /// Index of the first source in this chunk.
    pub first_source: u64,
    /// The sources, in order.
    pub sources: Vec<SourceRecord>,
}

/// Why a batch file was refused.
#[derive(Clone, Debug, PartialEq)]
pub enum BatchFileError {
    /// Reading or writing failed.
    Io {
        /// The file.
        path: PathBuf,
        /// The system's message.
        message: String,
    },
    /// The file does not start with [`MAGIC`]: not a trajectory batch.
    BadMagic {
        /// The first bytes found.
        found: Vec<u8>,
    },
    /// A format version this code does not read.
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Version supported.
        supported: u32,
    },
    /// The header is damaged.
    HeaderCorrupt {
        /// What is wrong.
        reason: String,
    },
    /// The file ends inside a chunk (a generation killed while writing, or a cut copy).
    Truncated {
        /// Index of the chunk that is cut.
        chunk: usize,
        /// File offset where the chunk starts.
        offset: u64,
        /// Bytes the chunk needs.
        needed: u64,
        /// Bytes there are.
        available: u64,
    },
    /// A chunk fails its CRC or does not decode.
    ChunkCorrupt {
        /// Index of the chunk.
        chunk: usize,
        /// File offset where the chunk starts.
        offset: u64,
        /// What is wrong.
        reason: String,
    },
    /// The file is intact but covers fewer sources than its header promises.
    Incomplete {
        /// Sources stored.
        sources_done: u64,
        /// Sources in the header.
        sources_total: u64,
    },
    /// The file was made with other parameters or sources than requested.
    Mismatch {
        /// The header field that differs.
        field: &'static str,
        /// Its value in the file.
        in_file: String,
        /// The value requested.
        requested: String,
    },
    /// A source trajectory cannot be stored (e.g. more obstacles than a scene can hold).
    Unstorable {
        /// What is wrong.
        reason: String,
    },
}

impl fmt::Display for BatchFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BatchFileError::Io { path, message } => write!(f, "{}: {message}", path.display()),
            BatchFileError::BadMagic { found } => write!(
                f,
                "not a trajectory batch file (magic {found:02x?}, expected \"WLTRAJB\\0\")"
            ),
            BatchFileError::UnsupportedVersion { found, supported } => write!(
                f,
                "trajectory batch format version {found} is not supported (this build reads \
                 version {supported}); regenerate the batch"
            ),
            BatchFileError::HeaderCorrupt { reason } => {
                write!(f, "trajectory batch header is corrupt: {reason}")
            }
            BatchFileError::Truncated {
                chunk,
                offset,
                needed,
                available,
            } => write!(
                f,
                "trajectory batch is truncated: chunk {chunk} at byte {offset} needs {needed} \
                 bytes, {available} remain (an interrupted generation: run it again to resume)"
            ),
            BatchFileError::ChunkCorrupt {
                chunk,
                offset,
                reason,
            } => write!(
                f,
                "trajectory batch chunk {chunk} at byte {offset} is corrupt: {reason}"
            ),
            BatchFileError::Incomplete {
                sources_done,
                sources_total,
            } => write!(
                f,
                "trajectory batch is incomplete: {sources_done} of {sources_total} source \
                 trajectories stored (run the generation again to resume)"
            ),
            BatchFileError::Mismatch {
                field,
                in_file,
                requested,
            } => write!(
                f,
                "trajectory batch was made with {field} = {in_file}, requested {requested}; \
                 delete it or choose another output"
            ),
            BatchFileError::Unstorable { reason } => {
                write!(f, "cannot store trajectory: {reason}")
            }
        }
    }
}

impl std::error::Error for BatchFileError {}

fn io_error(path: &Path, e: std::io::Error) -> BatchFileError {
    BatchFileError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32_matches_the_standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    #[test]
    fn obstacles_pack_exactly_and_off_grid_ones_are_refused() {
        for kind in ObstacleKind::ALL {
            for yaw in [ObstacleYaw::Deg0, ObstacleYaw::Deg90] {
                for (x, y) in [(-7, 3), (0, -1), (40, 12)] {
                    let o = Obstacle::new(kind, cell_centre_m(x), cell_centre_m(y), yaw);
                    let packed = PackedObstacle::pack(&o).unwrap();
                    assert_eq!(packed.unpack(), Some(o));
                }
            }
        }
        let off = Obstacle::new(ObstacleKind::Bar, 0.3, 0.125, ObstacleYaw::Deg0);
        assert_eq!(PackedObstacle::pack(&off), None);
        assert_eq!(
            PackedObstacle::pack(&Obstacle::new(
                ObstacleKind::Bar,
                1e9,
                0.125,
                ObstacleYaw::Deg0
            )),
            None
        );
    }
}
