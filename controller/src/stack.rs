//! The robot's decision stack, as the controller runs it: the int8 policy on the observation,
//! then the decision rule that never repeats a refused action, the collision guard on the fine
//! window and the arrival rule (`wheelleg_runtime::{decision, guard, arrival}`).
//!
//! This file depends on `wheelleg_runtime` alone, so that the host's test-vector generator and
//! evaluation (`examples/mcu_vectors.rs`) compile this very file and decide with the same code
//! as the firmware.

use wheelleg_runtime::action::{Action, CHOICES, DIMS};
use wheelleg_runtime::arrival::{Arrival, DEFAULT_RADIUS_M};
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{
    CollisionGuard, FineWindow, HeightMapRef, Refusal, WindowBounds, DEFAULT_MARGIN_M,
};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::{
    InferError, Kernel, LoadError, Outputs, Policy, UnsupportedKernel, ACTION_LOGITS,
};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_runtime::robot::Robot;

/// Cells per side of the robot-centred fine map the window is cut from (the host's
/// `MapGrid::GUARD_FINE`).
pub const FINE_SIDE: usize = 128;
/// Cell side of the fine map.
pub const FINE_CELL_M: f32 = 0.01;
/// Capacity of the fine window, in cells: the whole 1 cm map, so that the window of any robot
/// fits ([`CollisionGuard::fine_window`] is cut from the map; the shipped robot's default guard
/// reads 68 x 78 = 5,304 cells, the strider's 78 x 88 = 6,864).
pub const WINDOW_CELLS: usize = FINE_SIDE * FINE_SIDE;
/// Bytes of the fine window (`i16` heights).
pub const WINDOW_BYTES: usize = 2 * WINDOW_CELLS;
/// int8 elements of each activation buffer (the first conv layer's 16 x 16 x 16 output).
pub const ACTIVATION_ELEMENTS: usize = 4_096;
/// int16 elements of the row buffer: four conv 3 patches of 288 (eight of conv 2, 72 of
/// conv 1), at least the longest row (the dense layer's 516 inputs) padded to whole 16-element
/// blocks. Each conv batch has a fixed set-up cost, so fewer, larger batches are faster.
pub const ROW_ELEMENTS: usize = 1_152;
/// Bytes a link frame adds around the fine window's heights (the envelope's version, the
/// message's tag and the heights' length, the CRC), with room to spare.
pub const FRAME_OVERHEAD_BYTES: usize = 16;
/// The work area: inference's two activation buffers, then (after inference) the fine
/// window, in the same bytes; the observation link's frames arrive in it too.
pub const WORK_BYTES: usize = if WINDOW_BYTES + FRAME_OVERHEAD_BYTES > 2 * ACTIVATION_ELEMENTS {
    WINDOW_BYTES + FRAME_OVERHEAD_BYTES
} else {
    2 * ACTIVATION_ELEMENTS
};

/// Observations whose taken actions the decision rule remembers: an episode's 100 decisions
/// (the host's `EnvConfig::max_steps`) meet at most 100 distinct observations, so within an
/// episode this remembers exactly what the host's 128 do, in 1,120 fewer bytes.
pub const CONTROLLER_STATES: usize = 100;

/// A decision's deadline, from its fine window's arrival: the decision rule, guard and
/// arrival stop there ([`Stack::decide_in_time`]) and the robot holds. Above the slowest
/// decision measured on the held-out vectors (14.8 M instructions with inference, 87 ms at
/// 170 MHz), so that no decision a policy makes there is abandoned on the reference part.
pub const DECISION_DEADLINE_MS: u32 = 100;

/// The policy with the controller's buffer sizes.
pub type ControllerPolicy<'w> = Policy<'w, ACTIVATION_ELEMENTS, ROW_ELEMENTS>;

/// One observation as the policy reads it: the 32 x 32 height map and the state (clearance,
/// track, target x, target y in the robot frame), all in millimetres.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Observation {
    /// Row-major, row 0 ahead, column 0 left.
    pub height_mm: [i16; HEIGHT_MAP_CELLS],
    /// Clearance, track, target x, target y.
    pub state_mm: [i32; STATE_LEN],
}

impl Observation {
    /// Flat ground, legs and target at zero.
    pub const fn new() -> Observation {
        Observation {
            height_mm: [0; HEIGHT_MAP_CELLS],
            state_mm: [0; STATE_LEN],
        }
    }

    /// Takes the observation link's message in: the height map as `i16` little-endian
    /// millimetres, row-major, and the state. Whether it was taken: a map of another size is
    /// refused, and the last observation kept.
    #[must_use]
    pub fn read(&mut self, height_mm_le: &[u8], state_mm: [i32; STATE_LEN]) -> bool {
        if height_mm_le.len() != 2 * self.height_mm.len() {
            return false;
        }
        for (cell, pair) in self.height_mm.iter_mut().zip(height_mm_le.chunks_exact(2)) {
            *cell = i16::from_le_bytes([
                pair.first().copied().unwrap_or(0),
                pair.get(1).copied().unwrap_or(0),
            ]);
        }
        self.state_mm = state_mm;
        true
    }

    /// The leg configuration the state reports.
    pub fn legs(&self) -> LegConfig {
        let [clearance_mm, track_mm, _, _] = self.state_mm;
        LegConfig {
            clearance_m: clearance_mm as f32 * 1.0e-3,
            track_m: track_mm as f32 * 1.0e-3,
        }
    }
}

impl Default for Observation {
    fn default() -> Self {
        Self::new()
    }
}

/// What one decision produced: the record the firmware and the host compare byte for byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecisionRecord {
    /// The policy's int16 action logits.
    pub logits: [i16; ACTION_LOGITS],
    /// The greedy joint action (argmax per head), as a joint index.
    pub greedy: u8,
    /// The guard's strict verdict on the greedy action: 0 clear, 1 collision, 2 unreachable.
    pub greedy_verdict: u8,
    /// The action taken, as a joint index.
    pub action: u8,
    /// The guard's level that passed it (0 strict, 1 lenient), 255 if none did.
    pub level: u8,
    /// Candidates the decision rule checked.
    pub checks: u16,
}

impl DecisionRecord {
    /// Bytes of [`Self::to_bytes`].
    pub const BYTES: usize = 2 * ACTION_LOGITS + 6;

    /// Little-endian: logits, greedy, verdict, action, level, checks.
    pub fn to_bytes(self) -> [u8; Self::BYTES] {
        let mut out = [0u8; Self::BYTES];
        let (logits, rest) = out.split_at_mut(2 * ACTION_LOGITS);
        for (slot, logit) in logits.chunks_exact_mut(2).zip(self.logits) {
            slot.copy_from_slice(&logit.to_le_bytes());
        }
        let [checks_lo, checks_hi] = self.checks.to_le_bytes();
        for (slot, byte) in rest.iter_mut().zip([
            self.greedy,
            self.greedy_verdict,
            self.action,
            self.level,
            checks_lo,
            checks_hi,
        ]) {
            *slot = byte;
        }
        out
    }

    /// The action taken.
    pub fn action(&self) -> Action {
        Action::from_index(usize::from(self.action)).unwrap_or(Action::IDLE)
    }
}

/// Why the stack cannot decide.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StackError {
    /// The weights file was refused at boot.
    Load(LoadError),
    /// Inference failed.
    Infer(InferError),
    /// The guard's fine window does not fit [`WINDOW_CELLS`] (or its bytes are short).
    Window,
    /// The decision ran past its deadline and was abandoned ([`Stack::decide_in_time`]).
    DeadlineMissed,
}

/// The decision rule's memory at the controller's capacity (4 KB: a firmware keeps it in a
/// `static`, so that it is never moved).
pub type ControllerDecider = Decider<CONTROLLER_STATES>;

/// The robot's decision stack: policy, decision rule (its memory borrowed), guard on the fine
/// window, arrival.
#[derive(Debug)]
pub struct Stack<'w, 'd, const STATES: usize = CONTROLLER_STATES> {
    policy: ControllerPolicy<'w>,
    decider: &'d mut Decider<STATES>,
    guard: CollisionGuard,
    window: WindowBounds,
}

impl<'w, 'd, const STATES: usize> Stack<'w, 'd, STATES> {
    /// Checks the weights file (the boot check), takes the robot it was trained for from it and
    /// sets up the guard for that robot with its default margin; the decision rule starts
    /// afresh in `decider`.
    pub fn new(weights: &'w [u8], decider: &'d mut Decider<STATES>) -> Result<Self, StackError> {
        let policy = ControllerPolicy::from_bytes(weights).map_err(StackError::Load)?;
        let robot = policy.model().trained_for.robot;
        let guard = CollisionGuard::new(&robot, DEFAULT_MARGIN_M);
        let window = guard.fine_window(FINE_SIDE, FINE_CELL_M);
        if window.cells() > WINDOW_CELLS {
            return Err(StackError::Window);
        }
        decider.reset();
        Ok(Stack {
            policy,
            decider,
            guard,
            window,
        })
    }

    /// The robot the weights were trained for: what the control loop drives.
    pub fn robot(&self) -> Robot {
        self.policy.model().trained_for.robot
    }

    /// The part of the fine map the guard reads.
    pub fn window(&self) -> WindowBounds {
        self.window
    }

    /// The policy.
    pub fn policy(&self) -> &ControllerPolicy<'w> {
        &self.policy
    }

    /// Runs inference with `kernel` from now on (the check harness runs the portable scalar
    /// kernel beside the fastest one); refuses a kernel this target cannot run.
    pub fn set_kernel(&mut self, kernel: Kernel) -> Result<(), UnsupportedKernel> {
        self.policy.set_kernel(kernel)
    }

    /// A new episode: forget the actions taken.
    pub fn reset(&mut self) {
        self.decider.reset();
    }

    /// The policy's outputs on `observation`, in `work` (at least [`WORK_BYTES`]: split into
    /// the two activation buffers) and `row`.
    pub fn infer(
        &self,
        observation: &Observation,
        work: &mut [i8],
        row: &mut [i16],
    ) -> Result<Outputs, StackError> {
        let (ping, pong) = work
            .split_at_mut_checked(ACTIVATION_ELEMENTS)
            .ok_or(StackError::Infer(InferError::Internal))?;
        self.policy
            .evaluate_in(
                ping,
                pong,
                row,
                &observation.height_mm,
                &observation.state_mm,
            )
            .map_err(StackError::Infer)
    }

    /// The decision on `observation` with the policy's `outputs` and the fine window's
    /// heights (`i16` little-endian millimetres, [`Self::window`]'s cells): the guard's choice
    /// among the decision rule's candidates, an arriving action first where one applies.
    pub fn decide(
        &mut self,
        observation: &Observation,
        outputs: &Outputs,
        window_mm_le: &[u8],
    ) -> Result<DecisionRecord, StackError> {
        self.decide_in_time(observation, outputs, window_mm_le, || true)
    }

    /// [`Self::decide`] with a deadline: `in_time` is asked before each of the guard's checks,
    /// and once it says no the decision is abandoned ([`StackError::DeadlineMissed`], nothing
    /// remembered): the firmware's bound on a decision's time.
    pub fn decide_in_time(
        &mut self,
        observation: &Observation,
        outputs: &Outputs,
        window_mm_le: &[u8],
        in_time: impl FnMut() -> bool,
    ) -> Result<DecisionRecord, StackError> {
        let window = FineWindow::new(window_mm_le, self.window).map_err(|_| StackError::Window)?;
        self.decide_on_in_time(observation, outputs, HeightMapRef::Window(&window), in_time)
            .ok_or(StackError::DeadlineMissed)
    }

    /// [`Self::decide`] with the guard reading `map` (for the host's comparisons with other
    /// maps; the firmware reads its window).
    pub fn decide_on(
        &mut self,
        observation: &Observation,
        outputs: &Outputs,
        map: HeightMapRef<'_>,
    ) -> DecisionRecord {
        let decided = self.decide_on_in_time(observation, outputs, map, || true);
        // Never out of time, so always decided.
        decided.unwrap_or(DecisionRecord {
            logits: outputs.action_logits,
            greedy: index_u8(outputs.action()),
            greedy_verdict: 0,
            action: index_u8(Action::IDLE),
            level: u8::MAX,
            checks: 0,
        })
    }

    fn decide_on_in_time(
        &mut self,
        observation: &Observation,
        outputs: &Outputs,
        map: HeightMapRef<'_>,
        in_time: impl FnMut() -> bool,
    ) -> Option<DecisionRecord> {
        let legs = observation.legs();
        let key = ObservationKey::of_mm(&observation.height_mm, &observation.state_mm);
        let arrival = Arrival::from_state_mm(
            &observation.state_mm,
            DEFAULT_RADIUS_M,
            &self.policy.model().trained_for.robot.actions,
        );
        let greedy = outputs.action();
        let greedy_verdict = match self.guard.check(map, legs, greedy) {
            Ok(()) => 0,
            Err(Refusal::Collision) => 1,
            Err(Refusal::Unreachable) => 2,
        };
        let logits: &[i16; DIMS * CHOICES] = &outputs.action_logits;
        let checked = self.guard.choose_in_time(
            self.decider,
            key,
            logits,
            map,
            legs,
            Some(&arrival),
            in_time,
        )?;
        Some(DecisionRecord {
            logits: outputs.action_logits,
            greedy: index_u8(greedy),
            greedy_verdict,
            action: index_u8(checked.action),
            level: checked
                .level
                .map_or(u8::MAX, |level| u8::try_from(level).unwrap_or(u8::MAX)),
            checks: u16::try_from(checked.checks).unwrap_or(u16::MAX),
        })
    }
}

/// A joint action's index (below 243) as a byte.
fn index_u8(action: Action) -> u8 {
    u8::try_from(action.index()).unwrap_or(u8::MAX)
}
