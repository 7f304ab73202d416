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
pub mod robot;
pub mod stack_args;
pub mod train;

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
