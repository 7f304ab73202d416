//! The subcommands.

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

/// A command's failure: a message for the user.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;
