//! The subcommands.

/// `println!` to stdout, except that a reader that went away (`wheelleg eval --json | head`)
/// ends the program quietly, as command-line tools do, where `println!` would panic.
macro_rules! outln {
    () => {
        $crate::cli::write_stdout(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::cli::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

pub mod demo;
pub mod eval;
pub mod export;
pub mod generate;
pub mod inspect;
pub mod plan;
pub mod plot;
pub mod relevance;
pub mod render;
pub mod train;

/// The map the collision guard reads (`--guard-map` of `eval` and `demo`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GuardMapArg {
    /// The policy's own 5 cm map.
    Policy,
    /// A 1 cm map of the robot's surroundings, as a robot's elevation mapping keeps
    /// (`MapGrid::GUARD_FINE`; docs/results.md, "A finer map for the guard").
    Fine,
}

impl GuardMapArg {
    /// The layout of the map the guard reads when it is not the policy's.
    pub fn grid(self) -> Option<wheelleg_sim::height_map::MapGrid> {
        match self {
            GuardMapArg::Policy => None,
            GuardMapArg::Fine => Some(wheelleg_sim::height_map::MapGrid::GUARD_FINE),
        }
    }
}

/// A command's failure: a message for the user.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Writes to stdout. A closed pipe exits with status 141 (128 + SIGPIPE, what a shell reports
/// for a program killed by the signal) without a message; any other write error is reported.
pub fn write_stdout(args: std::fmt::Arguments<'_>) {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    if let Err(error) = stdout.write_fmt(args) {
        if error.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(141);
        }
        eprintln!("wheelleg: cannot write to stdout: {error}");
        std::process::exit(1);
    }
}
