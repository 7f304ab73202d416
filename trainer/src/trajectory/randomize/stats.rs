//! What a batch generation reports: its progress as it goes, and its counts at the end.

use crate::trajectory::batch_file::SourceRecord;
use wheelleg_sim::generate::Behaviour;

/// Progress of a batch generation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    /// Sources done (including those already in a resumed file).
    pub sources_done: u64,
    /// Sources in all.
    pub sources_total: u64,
    /// Scenes tried so far.
    pub tried: u64,
    /// Scenes kept so far (originals included).
    pub kept: u64,
}

/// What a batch generation produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stats {
    /// Source trajectories.
    pub sources: u64,
    /// Sources rejected (not successful, off-grid obstacles, ...).
    pub sources_rejected: u64,
    /// The first few rejections: (source index, reason).
    pub rejections: Vec<(u64, String)>,
    /// Randomized scenes tried.
    pub tried: u64,
    /// Randomized scenes kept.
    pub kept: u64,
    /// Original scenes stored (with `include_original`).
    pub originals: u64,
    /// Kept / tried per behaviour, in [`Behaviour::ALL`] order.
    pub by_behaviour: [(u64, u64); Behaviour::ALL.len()],
    /// Source index the generation resumed at (0 for a fresh one).
    pub resumed_at_source: u64,
    /// Bytes of a half-written chunk cut off the partial file on resume.
    pub discarded_tail_bytes: u64,
    /// Size of the finished file.
    pub file_bytes: u64,
}

impl Stats {
    /// Stored trajectories (kept randomized scenes plus originals).
    pub fn trajectories(&self) -> u64 {
        self.kept + self.originals
    }

    /// File bytes per stored trajectory (header and source records included).
    pub fn bytes_per_trajectory(&self) -> f64 {
        self.file_bytes as f64 / self.trajectories().max(1) as f64
    }

    pub(super) fn count(&mut self, index: u64, record: &SourceRecord) {
        self.sources += 1;
        if !record.rejected.is_empty() {
            self.sources_rejected += 1;
            if self.rejections.len() < 20 {
                self.rejections.push((index, record.rejected.clone()));
            }
        }
        let randomized = record.scenes.len() as u64 - u64::from(record.original_included);
        self.tried += record.tried as u64;
        self.kept += randomized;
        self.originals += u64::from(record.original_included);
        let last = Behaviour::ALL.len() - 1;
        let b = &mut self.by_behaviour[(record.behaviour as usize).min(last)];
        b.0 += randomized;
        b.1 += record.tried as u64;
    }
}
