//! The file's bytes: the preamble and header, chunks, and the scan that checks them.

use super::*;

/// The bytes of a file holding only `header`.
pub fn header_bytes(header: &BatchHeader) -> Result<Vec<u8>, BatchFileError> {
    let encode = |e: postcard::Error| BatchFileError::HeaderCorrupt {
        reason: format!("cannot encode: {e}"),
    };
    let mut payload = postcard::to_allocvec(header).map_err(encode)?;
    if let Some(robot) = &header.robot {
        payload.extend(postcard::to_allocvec(&robot.to_toml()).map_err(encode)?);
    }
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
    let corrupt = |reason: String| BatchFileError::HeaderCorrupt { reason };
    let mut header: BatchHeader = match postcard::take_from_bytes(payload) {
        Ok((header, [])) => header,
        Ok((mut header, rest)) => {
            // After the fields, a robot other than the shipped one.
            let (text, tail): (String, &[u8]) =
                postcard::take_from_bytes(rest).map_err(|e| corrupt(format!("robot: {e}")))?;
            if !tail.is_empty() {
                return Err(corrupt("trailing bytes after the header".into()));
            }
            header.robot = Some(
                RobotDescription::from_toml(&text)
                    .map_err(|e| corrupt(format!("robot description: {e}")))?,
            );
            header
        }
        Err(e) => return Err(corrupt(e.to_string())),
    };
    if header.robot == Some(RobotDescription::shipped()) {
        header.robot = None;
    }
    header.simulated_robot()?;
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
/// chunk ended; `corrupt` makes the error of a reason.
fn check_chunk(
    chunk: &Chunk,
    header: &BatchHeader,
    yaw_steps_per_turn: i32,
    next_source: u64,
    corrupt: impl Fn(String) -> BatchFileError,
) -> Result<(), BatchFileError> {
    if chunk.first_source != next_source {
        return Err(corrupt(format!(
            "starts at source {}, expected {next_source}",
            chunk.first_source
        )));
    }
    if chunk.sources.is_empty() {
        return Err(corrupt("holds no sources".into()));
    }
    if next_source + chunk.sources.len() as u64 > header.sources {
        return Err(corrupt(format!(
            "runs past the header's {} sources",
            header.sources
        )));
    }
    let max_scenes = header.per_trajectory as usize + usize::from(header.include_original);
    for (i, s) in chunk.sources.iter().enumerate() {
        let at = |what: String| corrupt(format!("source {}: {what}", next_source + i as u64));
        if behaviour_of_code(s.behaviour).is_none() {
            return Err(at(format!("unknown behaviour code {}", s.behaviour)));
        }
        if s.start_yaw_steps as i32 >= yaw_steps_per_turn {
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
    // The header's robot was checked when it was read (`parse_header`).
    let yaw_steps_per_turn = match header.simulated_robot() {
        Ok(robot) => robot.yaw_steps_per_turn(),
        Err(problem) => {
            scan.problem = Some(problem);
            return scan;
        }
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
        if let Err(problem) = check_chunk(
            &chunk,
            header,
            yaw_steps_per_turn,
            scan.sources_done,
            corrupt,
        ) {
            scan.problem = Some(problem);
            break;
        }
        scan.sources_done += chunk.sources.len() as u64;
        scan.chunks.push(chunk);
        at += CHUNK_PREFIX_LEN + len;
        scan.valid_end = at as u64;
    }
    scan
}
