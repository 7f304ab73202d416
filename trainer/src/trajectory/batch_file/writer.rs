//! Writing a batch: chunks appended to `<out>.partial`, resumable, renamed when done.

use super::*;

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
