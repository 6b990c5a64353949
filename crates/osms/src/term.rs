//! Output that cannot crash the command. Rust's `println!` and `eprintln!` panic when the write
//! fails, so `osms ls | head -1` (a closed pipe) or a log on a failing disk (EIO) would end in a
//! panic. Here:
//!
//! - **stdout** (data: tables, JSON): a closed pipe ends the process quietly with status 141,
//!   the status a shell reports for a C tool that SIGPIPE killed (`yes | head -1`), so a
//!   pipeline with `set -o pipefail` reads it as they do; any other write error is reported on
//!   stderr and ends the process with status 1.
//! - **stderr** (messages, logs, progress): a failed write drops that line; the command goes on,
//!   so a make whose log reader went away still finishes its builds.
//! - **colour**: only when stderr is a terminal and `NO_COLOR` is unset (<https://no-color.org>).
//! - **what is said**: one [`Printer`] per command, from the global flags: `--quiet` silences
//!   messages ([`say!`]; errors and data stay), `--verbose` adds detail, `--no-progress` (or
//!   `--quiet`) hides the bars; commands read these here, not flags of their own.

use std::fmt::Arguments;
use std::io::{ErrorKind, IsTerminal, Write};

/// What a command says, as its global flags ask (see the module's rules).
#[derive(Debug, Clone, Copy)]
pub struct Printer {
    pub quiet: bool,
    pub verbose: bool,
    /// Progress bars are drawn (on stderr, and only where messages are).
    pub progress: bool,
}

impl Printer {
    pub fn new(global: &crate::cli::Global) -> Self {
        Printer {
            quiet: global.quiet,
            verbose: global.verbose,
            progress: !global.no_progress && !global.quiet,
        }
    }

    /// Whether messages are printed: for one that takes work to compose.
    pub fn says(&self) -> bool {
        !self.quiet
    }

    /// A message on stderr (a note, a warning, what a command wrote), unless `--quiet`.
    pub fn say(&self, args: Arguments<'_>) {
        if self.says() {
            err(args);
        }
    }
}

/// The status of a process that wrote to a closed pipe: 128 + SIGPIPE (13).
pub const EXIT_CLOSED_PIPE: i32 = 141;

/// Writes to stdout (see the module's rules).
pub fn out(args: Arguments<'_>) {
    let mut stdout = std::io::stdout().lock();
    if let Err(e) = stdout.write_fmt(args).and_then(|()| stdout.flush()) {
        drop(stdout);
        if e.kind() == ErrorKind::BrokenPipe {
            std::process::exit(EXIT_CLOSED_PIPE);
        }
        err(format_args!(
            "error: cannot write to standard output: {e}\n"
        ));
        std::process::exit(i32::from(crate::EXIT_FAILURE));
    }
}

/// Writes to stderr, dropping what cannot be written.
pub fn err(args: Arguments<'_>) {
    let mut stderr = std::io::stderr().lock();
    let _ = stderr.write_fmt(args);
}

/// Whether messages on stderr may carry ANSI colour codes.
pub fn colour() -> bool {
    std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty())
}

/// A log writer for `tracing`: stderr, dropping what cannot be written.
pub struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let _ = std::io::stderr().lock().write_all(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let _ = std::io::stderr().flush();
        Ok(())
    }
}

/// `println!` on stdout that cannot panic (see [`crate::term`]).
macro_rules! outln {
    () => { $crate::term::out(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::term::out(format_args!("{}\n", format_args!($($arg)*))) };
}

/// `print!` on stdout that cannot panic.
macro_rules! out {
    ($($arg:tt)*) => { $crate::term::out(format_args!($($arg)*)) };
}

/// `eprintln!` that drops what cannot be written.
macro_rules! errln {
    () => { $crate::term::err(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::term::err(format_args!("{}\n", format_args!($($arg)*))) };
}

/// A message line on stderr unless `--quiet`: `say!(ctx, "wrote {}", path)`.
macro_rules! say {
    ($ctx:expr, $($arg:tt)*) => { $ctx.printer.say(format_args!("{}\n", format_args!($($arg)*))) };
}
