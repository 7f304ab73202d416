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
use core::fmt;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use wheelleg_runtime::action::{Action, COUNT};
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::generate::Behaviour;
use wheelleg_sim::obstacle::{cell_centre_m, Obstacle, ObstacleKind, ObstacleYaw, GRID_CELL_M};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::{RobotState, YAW_STEPS_PER_TURN};

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
}

impl BatchHeader {
    /// The episode rules of the batch.
    pub fn env_config(&self) -> EnvConfig {
        EnvConfig {
            max_steps: self.max_steps,
            success_radius_m: self.success_radius_m,
            give_up_margin_m: self.give_up_margin_m,
            arena_margin_m: self.arena_margin_m,
            // Not stored: a stored trajectory has no undone action, so it is never paid.
            ..EnvConfig::default()
        }
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
    /// The start state.
    pub fn start_state(&self) -> RobotState {
        RobotState {
            position: Point2::new(self.start_x_m, self.start_y_m),
            yaw_steps: self.start_yaw_steps as i32,
            clearance_steps: self.start_clearance_steps as i32,
            track_steps: self.start_track_steps as i32,
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
            start_yaw_steps: s.start.yaw_steps.rem_euclid(YAW_STEPS_PER_TURN) as u8,
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

/// The bytes of a file holding only `header`.
pub fn header_bytes(header: &BatchHeader) -> Result<Vec<u8>, BatchFileError> {
    let payload = postcard::to_allocvec(header).map_err(|e| BatchFileError::HeaderCorrupt {
        reason: format!("cannot encode: {e}"),
    })?;
    let mut out = Vec::with_capacity(PREAMBLE_LEN + payload.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&crc32(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// The bytes of one chunk (prefix included).
pub fn chunk_bytes(chunk: &Chunk) -> Result<Vec<u8>, BatchFileError> {
    let payload = postcard::to_allocvec(chunk).map_err(|e| BatchFileError::Unstorable {
        reason: format!("cannot encode chunk: {e}"),
    })?;
    if payload.len() > MAX_CHUNK_BYTES {
        return Err(BatchFileError::Unstorable {
            reason: format!(
                "chunk of {} bytes exceeds the {MAX_CHUNK_BYTES}-byte limit",
                payload.len()
            ),
        });
    }
    let mut out = Vec::with_capacity(CHUNK_PREFIX_LEN + payload.len());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&crc32(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

fn le_u32(bytes: &[u8], at: usize) -> u32 {
    let mut word = [0u8; 4];
    word.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(word)
}

/// Decodes the header; returns it and the offset of the first chunk.
pub fn parse_header(bytes: &[u8]) -> Result<(BatchHeader, usize), BatchFileError> {
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != MAGIC {
        return Err(BatchFileError::BadMagic {
            found: bytes[..bytes.len().min(MAGIC.len())].to_vec(),
        });
    }
    if bytes.len() < PREAMBLE_LEN {
        return Err(BatchFileError::HeaderCorrupt {
            reason: format!(
                "file is {} bytes, shorter than the {PREAMBLE_LEN}-byte preamble",
                bytes.len()
            ),
        });
    }
    let version = le_u32(bytes, 8);
    if version != VERSION {
        return Err(BatchFileError::UnsupportedVersion {
            found: version,
            supported: VERSION,
        });
    }
    let len = le_u32(bytes, 12) as usize;
    if len > MAX_HEADER_BYTES || PREAMBLE_LEN + len > bytes.len() {
        return Err(BatchFileError::HeaderCorrupt {
            reason: format!(
                "header length {len} does not fit in the file's {} bytes",
                bytes.len()
            ),
        });
    }
    let payload = &bytes[PREAMBLE_LEN..PREAMBLE_LEN + len];
    if crc32(payload) != le_u32(bytes, 16) {
        return Err(BatchFileError::HeaderCorrupt {
            reason: "CRC-32 mismatch".into(),
        });
    }
    let header: BatchHeader = match postcard::take_from_bytes(payload) {
        Ok((header, [])) => header,
        Ok(_) => {
            return Err(BatchFileError::HeaderCorrupt {
                reason: "trailing bytes after the header".into(),
            })
        }
        Err(e) => {
            return Err(BatchFileError::HeaderCorrupt {
                reason: e.to_string(),
            })
        }
    };
    if header.new_obstacles_min > header.new_obstacles_max {
        return Err(BatchFileError::HeaderCorrupt {
            reason: "new_obstacles_min > new_obstacles_max".into(),
        });
    }
    Ok((header, PREAMBLE_LEN + len))
}

/// The chunks of a file after its header: every valid chunk, the offset where the valid part
/// ends, and the first problem (if any) that stopped the scan.
pub struct ChunkScan {
    /// Valid chunks in file order.
    pub chunks: Vec<Chunk>,
    /// Byte offset just past the last valid chunk.
    pub valid_end: u64,
    /// Sources covered by the valid chunks.
    pub sources_done: u64,
    /// What stopped the scan before the end of the file.
    pub problem: Option<BatchFileError>,
}

/// Checks that a decoded chunk is well-formed and continues the sources where the previous
/// chunk ended.
fn check_chunk(chunk: &Chunk, header: &BatchHeader, next_source: u64) -> Result<(), String> {
    if chunk.first_source != next_source {
        return Err(format!(
            "starts at source {}, expected {next_source}",
            chunk.first_source
        ));
    }
    if chunk.sources.is_empty() {
        return Err("holds no sources".into());
    }
    if next_source + chunk.sources.len() as u64 > header.sources {
        return Err(format!("runs past the header's {} sources", header.sources));
    }
    let max_scenes = header.per_trajectory as usize + usize::from(header.include_original);
    for (i, s) in chunk.sources.iter().enumerate() {
        let at = |what: String| format!("source {}: {what}", next_source + i as u64);
        if behaviour_of_code(s.behaviour).is_none() {
            return Err(at(format!("unknown behaviour code {}", s.behaviour)));
        }
        if s.start_yaw_steps as i32 >= YAW_STEPS_PER_TURN {
            return Err(at(format!(
                "start yaw step {} out of range",
                s.start_yaw_steps
            )));
        }
        if let Some(a) = s.actions.iter().find(|&&a| a as usize >= COUNT) {
            return Err(at(format!("action index {a} out of range")));
        }
        let finite = [s.start_x_m, s.start_y_m, s.target_x_m, s.target_y_m];
        if finite.iter().any(|v| !v.is_finite()) {
            return Err(at("non-finite start or target".into()));
        }
        if s.scenes.len() > max_scenes || s.tried as usize > header.per_trajectory as usize {
            return Err(at(format!(
                "{} scenes ({} tried) exceed the header's {} per trajectory",
                s.scenes.len(),
                s.tried,
                header.per_trajectory
            )));
        }
        let obstacles = s.kept.iter().chain(s.scenes.iter().flatten());
        if let Some(o) = obstacles.clone().find(|o| o.unpack().is_none()) {
            return Err(at(format!("unknown obstacle code {}", o.code)));
        }
        if s.scenes.iter().any(|scene| scene.len() > u16::MAX as usize) {
            return Err(at("a scene with more than 65535 obstacles".into()));
        }
    }
    Ok(())
}

/// Scans the chunks of a whole file (header already decoded; chunks start at `start`).
pub fn scan_chunks(bytes: &[u8], header: &BatchHeader, start: usize) -> ChunkScan {
    let mut scan = ChunkScan {
        chunks: Vec::new(),
        valid_end: start as u64,
        sources_done: 0,
        problem: None,
    };
    let mut at = start;
    while at < bytes.len() {
        let chunk_index = scan.chunks.len();
        let remaining = bytes.len() - at;
        if remaining < CHUNK_PREFIX_LEN {
            scan.problem = Some(BatchFileError::Truncated {
                chunk: chunk_index,
                offset: at as u64,
                needed: CHUNK_PREFIX_LEN as u64,
                available: remaining as u64,
            });
            break;
        }
        let len = le_u32(bytes, at) as usize;
        let corrupt = |reason: String| BatchFileError::ChunkCorrupt {
            chunk: chunk_index,
            offset: at as u64,
            reason,
        };
        if len > MAX_CHUNK_BYTES {
            scan.problem = Some(corrupt(format!(
                "length {len} exceeds the {MAX_CHUNK_BYTES}-byte limit"
            )));
            break;
        }
        if remaining < CHUNK_PREFIX_LEN + len {
            scan.problem = Some(BatchFileError::Truncated {
                chunk: chunk_index,
                offset: at as u64,
                needed: (CHUNK_PREFIX_LEN + len) as u64,
                available: remaining as u64,
            });
            break;
        }
        let payload = &bytes[at + CHUNK_PREFIX_LEN..at + CHUNK_PREFIX_LEN + len];
        if crc32(payload) != le_u32(bytes, at + 4) {
            scan.problem = Some(corrupt("CRC-32 mismatch".into()));
            break;
        }
        let chunk: Chunk = match postcard::take_from_bytes(payload) {
            Ok((chunk, [])) => chunk,
            Ok(_) => {
                scan.problem = Some(corrupt("trailing bytes after the records".into()));
                break;
            }
            Err(e) => {
                scan.problem = Some(corrupt(format!("does not decode: {e}")));
                break;
            }
        };
        if let Err(reason) = check_chunk(&chunk, header, scan.sources_done) {
            scan.problem = Some(corrupt(reason));
            break;
        }
        scan.sources_done += chunk.sources.len() as u64;
        scan.chunks.push(chunk);
        at += CHUNK_PREFIX_LEN + len;
        scan.valid_end = at as u64;
    }
    scan
}

/// Appends chunks to `<out>.partial` and renames it to `<out>` when done.
pub struct BatchWriter {
    partial: PathBuf,
    file: fs::File,
    next_source: u64,
    bytes: u64,
}

/// Where a resumed generation continues.
#[derive(Clone, Debug, PartialEq)]
pub struct ResumePoint {
    /// The first source still to generate.
    pub next_source: u64,
    /// Bytes of a half-written tail cut off the partial file.
    pub discarded_tail_bytes: u64,
    /// The chunks already in the file (their statistics count towards the batch's).
    pub chunks: Vec<Chunk>,
}

/// `<out>.partial`, the file a generation writes before it is complete.
pub fn partial_path(out: &Path) -> PathBuf {
    let mut name = out.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

impl BatchWriter {
    /// Starts `<out>.partial` afresh with `header`.
    pub fn create(out: &Path, header: &BatchHeader) -> Result<BatchWriter, BatchFileError> {
        let partial = partial_path(out);
        let bytes = header_bytes(header)?;
        wheelleg_sim::atomic_write(&partial, &bytes).map_err(|e| io_error(&partial, e))?;
        let file = fs::OpenOptions::new()
            .append(true)
            .open(&partial)
            .map_err(|e| io_error(&partial, e))?;
        Ok(BatchWriter {
            partial,
            file,
            next_source: 0,
            bytes: bytes.len() as u64,
        })
    }

    /// Continues `<out>.partial` if it exists (its header must equal `header`; a half-written
    /// tail is cut back to the last valid chunk), else starts it afresh.
    pub fn resume(
        out: &Path,
        header: &BatchHeader,
    ) -> Result<(BatchWriter, ResumePoint), BatchFileError> {
        let partial = partial_path(out);
        let bytes = match fs::read(&partial) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let writer = BatchWriter::create(out, header)?;
                return Ok((
                    writer,
                    ResumePoint {
                        next_source: 0,
                        discarded_tail_bytes: 0,
                        chunks: Vec::new(),
                    },
                ));
            }
            Err(e) => return Err(io_error(&partial, e)),
        };
        let (found, start) = parse_header(&bytes)?;
        if let Some((field, in_file, requested)) = found.first_difference(header) {
            return Err(BatchFileError::Mismatch {
                field,
                in_file: format!("{in_file} (in {})", partial.display()),
                requested,
            });
        }
        let scan = scan_chunks(&bytes, &found, start);
        let file = fs::OpenOptions::new()
            .append(true)
            .open(&partial)
            .map_err(|e| io_error(&partial, e))?;
        let discarded = bytes.len() as u64 - scan.valid_end;
        if discarded > 0 {
            file.set_len(scan.valid_end)
                .and_then(|()| file.sync_all())
                .map_err(|e| io_error(&partial, e))?;
        }
        Ok((
            BatchWriter {
                partial,
                file,
                next_source: scan.sources_done,
                bytes: scan.valid_end,
            },
            ResumePoint {
                next_source: scan.sources_done,
                discarded_tail_bytes: discarded,
                chunks: scan.chunks,
            },
        ))
    }

    /// The next source index the file expects.
    pub fn next_source(&self) -> u64 {
        self.next_source
    }

    /// Bytes written so far (header included).
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Appends one chunk and syncs it to disk; `chunk.first_source` must be
    /// [`BatchWriter::next_source`].
    pub fn append(&mut self, chunk: &Chunk) -> Result<(), BatchFileError> {
        if chunk.first_source != self.next_source || chunk.sources.is_empty() {
            return Err(BatchFileError::Unstorable {
                reason: format!(
                    "chunk starts at source {} with {} sources, the file expects source {}",
                    chunk.first_source,
                    chunk.sources.len(),
                    self.next_source
                ),
            });
        }
        let bytes = chunk_bytes(chunk)?;
        // One write per chunk, then fsync: a crash leaves at most this chunk half-written,
        // which the CRC and length expose and a resume cuts off.
        self.file
            .write_all(&bytes)
            .and_then(|()| self.file.sync_data())
            .map_err(|e| io_error(&self.partial, e))?;
        self.next_source += chunk.sources.len() as u64;
        self.bytes += bytes.len() as u64;
        Ok(())
    }

    /// Renames the finished partial file to `out`.
    pub fn finish(self, out: &Path) -> Result<(), BatchFileError> {
        self.file
            .sync_all()
            .map_err(|e| io_error(&self.partial, e))?;
        drop(self.file);
        fs::rename(&self.partial, out).map_err(|e| io_error(out, e))?;
        if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Best effort: makes the rename itself durable where the platform allows it.
            let _ = fs::File::open(dir).and_then(|d| d.sync_all());
        }
        Ok(())
    }
}

/// One source trajectory as held in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredSource {
    /// The source scenario's name.
    pub name: String,
    /// The behaviour whose secondary policy produced it.
    pub behaviour: Behaviour,
    /// Start.
    pub start: RobotState,
    /// Target.
    pub target: Point2<f32>,
    /// The actions (undone actions removed).
    pub actions: Vec<Action>,
    /// Obstacles in every scene of this source.
    pub kept: Vec<Obstacle>,
    /// Scenes tried.
    pub tried: u32,
    /// Scenes kept.
    pub scenes: u32,
    /// Whether the first scene is the source's own.
    pub original_included: bool,
    /// Why it was not randomized (empty when it was).
    pub rejected: String,
    /// Index of its first scene in the batch.
    pub first_scene: u32,
}

/// One scene in memory: 12 bytes plus 6 per new obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SceneRef {
    source: u32,
    first_obstacle: u32,
    obstacles: u16,
}

/// A whole batch in memory, compactly: sources once, scenes as references plus their new
/// obstacles. [`TrajectoryBatch::trajectory`] materializes one trajectory.
#[derive(Clone, Debug)]
pub struct TrajectoryBatch {
    header: BatchHeader,
    sources: Vec<StoredSource>,
    scenes: Vec<SceneRef>,
    obstacles: Vec<PackedObstacle>,
    file_bytes: u64,
}

impl TrajectoryBatch {
    /// Reads and checks a complete batch file.
    pub fn load(path: &Path) -> Result<TrajectoryBatch, BatchFileError> {
        let bytes = fs::read(path).map_err(|e| io_error(path, e))?;
        TrajectoryBatch::from_bytes(&bytes)
    }

    /// Decodes and checks the bytes of a complete batch file.
    pub fn from_bytes(bytes: &[u8]) -> Result<TrajectoryBatch, BatchFileError> {
        let (header, start) = parse_header(bytes)?;
        let scan = scan_chunks(bytes, &header, start);
        if let Some(problem) = scan.problem {
            return Err(problem);
        }
        if scan.sources_done != header.sources {
            return Err(BatchFileError::Incomplete {
                sources_done: scan.sources_done,
                sources_total: header.sources,
            });
        }
        let mut batch = TrajectoryBatch {
            header,
            sources: Vec::new(),
            scenes: Vec::new(),
            obstacles: Vec::new(),
            file_bytes: bytes.len() as u64,
        };
        for chunk in scan.chunks {
            for record in chunk.sources {
                batch.push_source(record)?;
            }
        }
        // Millions of scenes: the growth slack of the vectors would be a third of the memory.
        batch.scenes.shrink_to_fit();
        batch.obstacles.shrink_to_fit();
        Ok(batch)
    }

    fn push_source(&mut self, record: SourceRecord) -> Result<(), BatchFileError> {
        let too_big = || BatchFileError::Unstorable {
            reason: "more than 2^32 scenes or obstacles in memory".into(),
        };
        let source = u32::try_from(self.sources.len()).map_err(|_| too_big())?;
        let first_scene = u32::try_from(self.scenes.len()).map_err(|_| too_big())?;
        for scene in &record.scenes {
            self.scenes.push(SceneRef {
                source,
                first_obstacle: u32::try_from(self.obstacles.len()).map_err(|_| too_big())?,
                obstacles: scene.len() as u16,
            });
            self.obstacles.extend_from_slice(scene);
        }
        // Chunks were checked: every code and action index decodes.
        self.sources.push(StoredSource {
            name: record.name.clone(),
            behaviour: behaviour_of_code(record.behaviour).unwrap_or(Behaviour::Straight),
            start: record.start_state(),
            target: Point2::new(record.target_x_m, record.target_y_m),
            actions: record
                .actions
                .iter()
                .filter_map(|&a| Action::from_index(a as usize))
                .collect(),
            kept: record
                .kept
                .iter()
                .filter_map(PackedObstacle::unpack)
                .collect(),
            tried: record.tried,
            scenes: record.scenes.len() as u32,
            original_included: record.original_included,
            rejected: record.rejected,
            first_scene,
        });
        Ok(())
    }

    /// The header (parameters and episode rules).
    pub fn header(&self) -> &BatchHeader {
        &self.header
    }

    /// The episode rules every stored trajectory replays under.
    pub fn env_config(&self) -> EnvConfig {
        self.header.env_config()
    }

    /// Number of stored trajectories (scenes).
    pub fn len(&self) -> usize {
        self.scenes.len()
    }

    /// Whether no trajectory is stored.
    pub fn is_empty(&self) -> bool {
        self.scenes.is_empty()
    }

    /// The source trajectories.
    pub fn sources(&self) -> &[StoredSource] {
        &self.sources
    }

    /// The source of trajectory `index`.
    pub fn source_of(&self, index: usize) -> Option<&StoredSource> {
        self.scenes
            .get(index)
            .map(|scene| &self.sources[scene.source as usize])
    }

    /// Trajectory `index`: its scene is the source's start, target and kept obstacles plus the
    /// scene's new obstacles; its actions are the source's. `None` past the end.
    pub fn trajectory(&self, index: usize) -> Option<Trajectory> {
        let scene = self.scenes.get(index)?;
        let source = &self.sources[scene.source as usize];
        let first = scene.first_obstacle as usize;
        let new = &self.obstacles[first..first + scene.obstacles as usize];
        let mut obstacles = source.kept.clone();
        obstacles.extend(new.iter().filter_map(PackedObstacle::unpack));
        let k = index - source.first_scene as usize;
        let name = if source.original_included && k == 0 {
            source.name.clone()
        } else {
            format!("{}-r{k}", source.name)
        };
        Some(Trajectory {
            scenario: Scenario {
                name,
                start: source.start,
                target: source.target,
                obstacles,
            },
            actions: source.actions.clone(),
            behaviour: source.behaviour,
        })
    }

    /// Stored trajectories per behaviour, in [`Behaviour::ALL`] order.
    pub fn counts_by_behaviour(&self) -> [usize; Behaviour::ALL.len()] {
        let mut counts = [0; Behaviour::ALL.len()];
        for s in &self.sources {
            counts[behaviour_code(s.behaviour) as usize] += s.scenes as usize;
        }
        counts
    }

    /// Size of the file it was read from.
    pub fn file_bytes(&self) -> u64 {
        self.file_bytes
    }

    /// Approximate heap bytes held (scenes, obstacles, sources with their actions).
    pub fn memory_bytes(&self) -> usize {
        self.scenes.capacity() * std::mem::size_of::<SceneRef>()
            + self.obstacles.capacity() * std::mem::size_of::<PackedObstacle>()
            + self
                .sources
                .iter()
                .map(|s| {
                    std::mem::size_of::<StoredSource>()
                        + s.name.capacity()
                        + s.actions.capacity() * std::mem::size_of::<Action>()
                        + s.kept.capacity() * std::mem::size_of::<Obstacle>()
                        + s.rejected.capacity()
                })
                .sum::<usize>()
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
