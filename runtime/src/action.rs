//! The 5-D discrete action: each dimension steps by -1, 0 or +1 per decision.
//!
//! The policy has one 3-way categorical head per dimension, in the order of [`Dim::ALL`]; the
//! joint action space has 3^5 = 243 members, which planners enumerate by [`Action::from_index`].

/// Translation per step along the robot's own x or y axis.
pub const MOVE_STEP_M: f32 = 0.05;
/// Rotation per step about the vertical axis, in degrees (the yaw lattice).
pub const YAW_STEP_DEG: f32 = 5.0;
/// Body clearance change per step.
pub const CLEARANCE_STEP_M: f32 = 0.02;
/// Wheel track change per step.
pub const TRACK_STEP_M: f32 = 0.02;
/// The action lattice: how far one step of each dimension moves the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActionLattice {
    /// Translation per step along the robot's own x or y axis.
    pub move_step_m: f32,
    /// Rotation per step about the vertical axis, in degrees.
    pub yaw_step_deg: f32,
    /// Body clearance change per step.
    pub clearance_step_m: f32,
    /// Wheel track change per step.
    pub track_step_m: f32,
}

impl ActionLattice {
    /// The paper's lattice: 0.05 m, 5 degrees, 0.02 m, 0.02 m.
    pub const PAPER: ActionLattice = ActionLattice {
        move_step_m: MOVE_STEP_M,
        yaw_step_deg: YAW_STEP_DEG,
        clearance_step_m: CLEARANCE_STEP_M,
        track_step_m: TRACK_STEP_M,
    };
}

/// Number of action dimensions (policy heads).
pub const DIMS: usize = 5;
/// Number of choices per dimension.
pub const CHOICES: usize = 3;
/// Number of joint actions (3^5).
pub const COUNT: usize = 243;

/// One dimension's choice.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Step {
    /// Step down / backward / right / clockwise.
    Minus,
    /// Keep.
    #[default]
    Zero,
    /// Step up / forward / left / counter-clockwise.
    Plus,
}

impl Step {
    /// All choices in head order: index 0 is `Minus`, 1 `Zero`, 2 `Plus`.
    pub const ALL: [Step; 3] = [Step::Minus, Step::Zero, Step::Plus];

    /// -1, 0 or +1.
    pub const fn sign(self) -> i8 {
        match self {
            Step::Minus => -1,
            Step::Zero => 0,
            Step::Plus => 1,
        }
    }

    /// The choice's index within its policy head (0, 1, 2).
    pub const fn head_index(self) -> usize {
        match self {
            Step::Minus => 0,
            Step::Zero => 1,
            Step::Plus => 2,
        }
    }

    /// The choice at a head index; `None` past 2.
    pub const fn from_head_index(index: usize) -> Option<Step> {
        match index {
            0 => Some(Step::Minus),
            1 => Some(Step::Zero),
            2 => Some(Step::Plus),
            _ => None,
        }
    }
}

/// The five action dimensions, in policy head order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Dim {
    /// Move along the robot's x (forward).
    MoveX,
    /// Move along the robot's y (left).
    MoveY,
    /// Rotate about the vertical axis (counter-clockwise positive).
    Yaw,
    /// Change the body clearance.
    Clearance,
    /// Change the wheel track (leg width).
    Track,
}

impl Dim {
    /// All dimensions in head order.
    pub const ALL: [Dim; DIMS] = [Dim::MoveX, Dim::MoveY, Dim::Yaw, Dim::Clearance, Dim::Track];
}

/// One decision: a step choice for each dimension.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub struct Action {
    /// Move along the robot's x.
    pub move_x: Step,
    /// Move along the robot's y.
    pub move_y: Step,
    /// Rotate.
    pub yaw: Step,
    /// Change clearance.
    pub clearance: Step,
    /// Change track.
    pub track: Step,
}

impl Action {
    /// Do nothing.
    pub const IDLE: Action = Action {
        move_x: Step::Zero,
        move_y: Step::Zero,
        yaw: Step::Zero,
        clearance: Step::Zero,
        track: Step::Zero,
    };

    /// The choice along one dimension.
    pub const fn get(&self, dim: Dim) -> Step {
        match dim {
            Dim::MoveX => self.move_x,
            Dim::MoveY => self.move_y,
            Dim::Yaw => self.yaw,
            Dim::Clearance => self.clearance,
            Dim::Track => self.track,
        }
    }

    /// Sets the choice along one dimension.
    pub fn set(&mut self, dim: Dim, step: Step) {
        match dim {
            Dim::MoveX => self.move_x = step,
            Dim::MoveY => self.move_y = step,
            Dim::Yaw => self.yaw = step,
            Dim::Clearance => self.clearance = step,
            Dim::Track => self.track = step,
        }
    }

    /// Builds an action from the five heads' choices (head indices 0..3 each).
    pub fn from_head_indices(indices: [usize; DIMS]) -> Option<Action> {
        let mut action = Action::IDLE;
        for (dim, index) in Dim::ALL.into_iter().zip(indices) {
            action.set(dim, Step::from_head_index(index)?);
        }
        Some(action)
    }

    /// The five heads' choices.
    pub fn head_indices(&self) -> [usize; DIMS] {
        Dim::ALL.map(|dim| self.get(dim).head_index())
    }

    /// The joint action with index `index` (base-3 digits, `MoveX` most significant); `None`
    /// for `index >= 243`.
    pub fn from_index(index: usize) -> Option<Action> {
        if index >= COUNT {
            return None;
        }
        let mut rest = index;
        let mut digits = [0usize; DIMS];
        for digit in digits.iter_mut().rev() {
            *digit = rest % CHOICES;
            rest /= CHOICES;
        }
        Action::from_head_indices(digits)
    }

    /// This action's joint index, the inverse of [`Action::from_index`].
    pub fn index(&self) -> usize {
        self.head_indices()
            .into_iter()
            .fold(0, |acc, digit| acc * CHOICES + digit)
    }

    /// Whether the action moves the base (translation or rotation).
    pub fn moves_base(&self) -> bool {
        self.move_x != Step::Zero || self.move_y != Step::Zero || self.yaw != Step::Zero
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_round_trips_over_the_whole_action_space() {
        for index in 0..COUNT {
            let action = Action::from_index(index).unwrap();
            assert_eq!(action.index(), index);
        }
        assert_eq!(Action::from_index(COUNT), None);
        assert_eq!(Action::IDLE.index(), 121, "idle is the middle of the space");
    }
}
