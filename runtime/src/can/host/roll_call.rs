//! The start-up's roll call: who answers Get_Version on each node of the map, how often, and
//! with what firmware.

use super::*;

/// Get_Version rounds of the start-up [`RollCall`]: more than one, so that a lost frame is not
/// a missing node and a duplicated one is not a second device.
pub const ROLL_CALL_ROUNDS: u8 = 3;

/// How long each roll-call round waits for Get_Version answers. An axis answers within a
/// millisecond or two; the rest is room for a bus that delays frames and for a real-time link
/// through a busy host, so that a slow answer is not taken for a missing node (nor counted in
/// the next round as a second device).
pub const ROLL_CALL_ROUND_US: u64 = 50_000;

/// What is wrong with one node at the start-up roll call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RollCallProblem {
    /// Nothing heard from the node: no answer to Get_Version, no heartbeat, no estimate.
    Missing,
    /// Two devices on one node id: two different answers, or two answers to every request.
    TwoDevices,
    /// Firmware whose major.minor this codec does not speak (see
    /// [`Version::speaks_this_codec`]).
    UnsupportedFirmware(Version),
}

impl core::fmt::Display for RollCallProblem {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RollCallProblem::Missing => f.write_str(
                "missing: nothing heard from it (is it powered, on the bus, on this node id?)",
            ),
            RollCallProblem::TwoDevices => {
                f.write_str("answered Get_Version twice: two devices share this node id")
            }
            RollCallProblem::UnsupportedFirmware(version) => write!(
                f,
                "reports {version}; this controller speaks the CANSimple layout of \
                 firmware {}.{}.x only",
                crate::can::protocol::SPOKEN_FW_VERSION.0,
                crate::can::protocol::SPOKEN_FW_VERSION.1
            ),
        }
    }
}

/// Why the roll call refuses to let the robot move: the first axis, in node order, with a
/// problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RollCallRefusal {
    /// The axis.
    pub axis: Axis,
    /// Its node id.
    pub node: NodeId,
    /// What is wrong.
    pub problem: RollCallProblem,
}

impl core::fmt::Display for RollCallRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "node {} ({}): {}",
            self.node.get(),
            self.axis,
            self.problem
        )
    }
}

/// The start-up roll call: who answers Get_Version on each node of the map, how often, and with
/// what. Fixed-size, never allocates.
///
/// Use: for each of [`ROLL_CALL_ROUNDS`] rounds, [`RollCall::begin_round`], queue the requests
/// ([`Commander::queue_version_requests`]), hand every received frame to
/// [`RollCall::receive`] for a bounded time; then [`RollCall::verdict`].
#[derive(Clone, Debug, PartialEq)]
pub struct RollCall {
    map: NodeMap,
    rounds: u8,
    /// Answers per axis in the round in progress.
    this_round: [u8; AXIS_COUNT],
    /// Finished rounds in which the axis answered more than once.
    rounds_doubled: [u8; AXIS_COUNT],
    versions: [Option<Version>; AXIS_COUNT],
    conflicting: AxisSet,
    heard: AxisSet,
}

impl RollCall {
    /// A roll call of `map`'s nodes that has heard nothing yet.
    pub fn new(map: NodeMap) -> RollCall {
        RollCall {
            map,
            rounds: 0,
            this_round: [0; AXIS_COUNT],
            rounds_doubled: [0; AXIS_COUNT],
            versions: [None; AXIS_COUNT],
            conflicting: AxisSet::default(),
            heard: AxisSet::default(),
        }
    }

    /// Closes the round in progress, if any, and opens the next; call it before sending the
    /// round's requests.
    pub fn begin_round(&mut self) {
        self.close_round();
        self.rounds = self.rounds.saturating_add(1);
    }

    fn close_round(&mut self) {
        for (now, doubled) in self
            .this_round
            .iter_mut()
            .zip(self.rounds_doubled.iter_mut())
        {
            if *now >= 2 {
                *doubled = doubled.saturating_add(1);
            }
            *now = 0;
        }
    }

    /// Rounds begun so far.
    pub fn rounds(&self) -> u8 {
        self.rounds
    }

    /// Takes in a received frame: any frame from a mapped node shows it is on the bus; a
    /// version answer is recorded. Returns the axis whose version answer this was, if it was one.
    pub fn receive<F: Frame>(&mut self, frame: &F) -> Option<Axis> {
        let (node, message) = decode(frame).ok()?;
        let axis = self.map.axis_on(node)?;
        if !message.is_command() {
            self.heard.insert(axis);
        }
        match message {
            Message::Version(version) => {
                self.record(axis, version);
                Some(axis)
            }
            _ => None,
        }
    }

    /// Records one version answer from `axis` in the round in progress.
    pub fn record(&mut self, axis: Axis, version: Version) {
        let i = axis.index();
        self.heard.insert(axis);
        if let Some(count) = self.this_round.get_mut(i) {
            *count = count.saturating_add(1);
        }
        if let Some(slot) = self.versions.get_mut(i) {
            match slot {
                None => *slot = Some(version),
                // A bus may repeat a frame but never alters one: different contents on one id
                // are two devices.
                Some(first) if *first != version => self.conflicting.insert(axis),
                Some(_) => {}
            }
        }
    }

    /// The version `axis` reported (its first answer), if it answered.
    pub fn version(&self, axis: Axis) -> Option<Version> {
        self.versions.get(axis.index()).copied().flatten()
    }

    /// The axes that answered Get_Version at least once.
    pub fn answered(&self) -> AxisSet {
        let mut set = AxisSet::default();
        for axis in Axis::ALL {
            if self.version(axis).is_some() {
                set.insert(axis);
            }
        }
        set
    }

    /// The axes anything was heard from (a version answer or any other report).
    pub fn heard(&self) -> AxisSet {
        self.heard
    }

    /// Whether every node may be driven: each answered, once per request, with firmware this
    /// codec speaks. Otherwise the first axis in node order with a problem. The round in
    /// progress counts as finished.
    pub fn verdict(&self) -> Result<(), RollCallRefusal> {
        let rounds = self.rounds.max(1);
        for axis in Axis::ALL {
            let i = axis.index();
            let now = self.this_round.get(i).copied().unwrap_or(0);
            let doubled = self
                .rounds_doubled
                .get(i)
                .copied()
                .unwrap_or(0)
                .saturating_add(u8::from(now >= 2));
            let problem = match self.version(axis) {
                // ODrive firmware before 0.6 has no Get_Version: a node heard otherwise (its
                // heartbeat) runs the 0.5.x layout this codec speaks.
                None if self.heard.contains(axis) => None,
                None => Some(RollCallProblem::Missing),
                // A bus that repeats a frame now and then doubles an answer in some round,
                // rarely in every round; a second device answers twice every time.
                Some(_) if self.conflicting.contains(axis) || doubled >= rounds => {
                    Some(RollCallProblem::TwoDevices)
                }
                Some(version) if !version.speaks_this_codec() => {
                    Some(RollCallProblem::UnsupportedFirmware(version))
                }
                Some(_) => None,
            };
            if let Some(problem) = problem {
                return Err(RollCallRefusal {
                    axis,
                    node: self.map.node_id(axis),
                    problem,
                });
            }
        }
        Ok(())
    }
}
