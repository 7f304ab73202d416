//! The subcommands.

pub mod generate;
pub mod plan;
pub mod render;

/// A command's failure: a message for the user.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;
