//! What the soak counts and measures over all its episodes.

/// Figures of the whole soak, printed at the end (docs/robustness.md quotes them).
#[derive(Debug, Default)]
pub(crate) struct Figures {
    pub(crate) episodes: u32,
    pub(crate) steps: u32,
    pub(crate) succeeded: u32,
    pub(crate) safe_stops_silent: u32,
    pub(crate) safe_stops_error: u32,
    pub(crate) off_tolerance: u32,
    pub(crate) frames_sent: u64,
    pub(crate) dropped: u64,
    pub(crate) delayed: u64,
    pub(crate) duplicated: u64,
    pub(crate) worst_silence_detection_us: u64,
    pub(crate) watchdog_trips: u32,
    pub(crate) worst_watchdog_us: u64,
    pub(crate) best_watchdog_us: u64,
    pub(crate) true_pose_checks: u32,
    pub(crate) worst_true_drift_m: f32,
    /// Episodes whose true pose touched an obstacle at any control tick (asserted empty).
    pub(crate) contacts: Vec<u64>,
    /// Stops in the middle of a step (silent node, or a watchdog trip the lossy bus caused).
    pub(crate) mid_step_stops: u32,
    /// Silent nodes that still heard commands / that dropped off the bus.
    pub(crate) silent_hearing: u32,
    pub(crate) silent_disconnected: u32,
    /// Per injected fault (silent node still hearing, node off the bus, controller hung,
    /// none: a watchdog trip the lossy bus caused): longest time from the stop decision until
    /// the true pose stopped moving (< 10 µm and 10 µrad per control tick), and the largest
    /// distance of the stopped robot's true rest pose from the path of the step it stopped in
    /// (nearest of the path's poses at every 1 % of progress): position, heading, clearance
    /// and track.
    pub(crate) stops: [StopFigures; 4],
}

/// Figures of the stops of one kind of fault.
#[derive(Debug, Default)]
pub(crate) struct StopFigures {
    pub(crate) kind: &'static str,
    pub(crate) stops: u32,
    pub(crate) worst_stop_to_rest_us: u64,
    pub(crate) worst_off_path_m: f32,
    pub(crate) worst_off_path_rad: f32,
    pub(crate) worst_off_path_legs_m: f32,
}
