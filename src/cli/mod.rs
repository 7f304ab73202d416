//! The subcommands.

pub mod generate;
pub mod plan;
pub mod render;
pub mod train;
pub mod eval;
pub mod plot;

/// A command's failure: a message for the user.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;
