//! `isostream`: the command line. All flag handling lives here; the work is in the crates.
//!
//! Errors reach the user as one line (`error: ...`) naming the file and the fix, with a
//! non-zero exit code: 2 for a bad job or bad input (a mesh given to check, convert, measure or
//! report included, and a service configuration `serve` refuses), 130 for a run or conversion
//! stopped by Ctrl-C, SIGTERM or SIGHUP, 1 otherwise (a failed write of the answer to stdout
//! included, `> /dev/full`, and an output locked by another run or conversion). A stdout whose
//! reader closed it (`| head`) ends the command quietly with 0, as `serve` does when a signal
//! stops it (a clean stop). README.md lists them.

#![deny(unsafe_code)]

mod cli;
mod logging;
mod measure_cmd;
mod progress;
mod run_cmd;
mod serve_cmd;
mod stdout;

use std::process::ExitCode;

use clap::Parser;

/// glibc's allocator tuned for a bounded-memory run.
///
/// The mmap threshold is fixed: glibc raises it each time a large mmapped block is freed, so
/// the simplifier's vectors, regrown all run long, ended up in the main heap, and peak RSS
/// crept up by 10 MiB at a constant resident surface (engine at R = 0.2 in two stages: 68 MiB;
/// with the threshold fixed at 128 KiB, 58 MiB). mimalloc, tried instead, held 170 MiB.
///
/// The arenas are as many as the cores, and at most [`MAX_ARENAS`]: glibc makes up to 8 per
/// core, one per thread that allocates, each reserving 64 MiB of address space, so bonsai's
/// default job (48 MiB resident) reserved 623 MB and an address-space cap (`ulimit -v 400000`,
/// as HPC schedulers set) aborted it in the allocator. With 2 arenas on 2 cores it reserves 154
/// MB at the same peak RSS, and its threads barely wait on an arena (the run's futex calls:
/// 3,045 with glibc's default, 3,339 with 2). A user's own `MALLOC_ARENA_MAX` (or glibc
/// tunables) is left in charge.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn tune_allocator() {
    let user_set = ["MALLOC_ARENA_MAX", "GLIBC_TUNABLES"]
        .iter()
        .any(|v| std::env::var_os(v).is_some());
    let arenas = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(MAX_ARENAS);
    // SAFETY: `mallopt` only sets allocator tunables; it is called first thing in `main`,
    // before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 128 * 1024);
        if !user_set {
            libc::mallopt(
                libc::M_ARENA_MAX,
                libc::c_int::try_from(arenas).unwrap_or(libc::c_int::MAX),
            );
        }
    }
}

/// Arenas on a many-core node: a run's threads are its stages (4 to 6) and one extraction
/// worker per core (up to 8 unless `[pipeline] threads` asks for more), and 8 arenas (512 MiB of address space) serve them where glibc's default
/// reserved 64 MiB for each.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MAX_ARENAS: usize = 8;

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn tune_allocator() {}

/// Whether SIGHUP was ignored when the process started (`nohup`, or a supervisor that sets it
/// so): then a closed terminal must not stop it, though the handlers installed later (ctrlc's
/// for `run`, tokio's for `serve`) would catch the signal. Read first thing in `main`.
static HANGUP_IGNORED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();

pub(crate) fn hangup_ignored() -> bool {
    HANGUP_IGNORED.get().copied().unwrap_or(false)
}

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn hangup_ignored_at_start() -> bool {
    // SAFETY: a null new action only reads SIGHUP's current disposition into `old`, a plain
    // struct zeroed first; nothing is changed.
    unsafe {
        let mut old: libc::sigaction = std::mem::zeroed();
        libc::sigaction(libc::SIGHUP, std::ptr::null(), &mut old) == 0
            && old.sa_sigaction == libc::SIG_IGN
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn hangup_ignored_at_start() -> bool {
    false
}

/// Puts SIGHUP back to ignored after a handler library took it (see [`HANGUP_IGNORED`]).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
pub(crate) fn keep_hangup_ignored() {
    if hangup_ignored() {
        // SAFETY: sets SIGHUP's disposition to SIG_IGN, which installs no handler code.
        unsafe {
            libc::signal(libc::SIGHUP, libc::SIG_IGN);
        }
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub(crate) fn keep_hangup_ignored() {}

fn main() -> ExitCode {
    tune_allocator();
    let _ = HANGUP_IGNORED.set(hangup_ignored_at_start());
    let cli = match cli::Cli::try_parse() {
        Ok(cli) => cli,
        // --help and --version (exit 0), and the help shown for a bare `isostream` (exit 2):
        // their text as clap lays it out.
        Err(e)
            if !e.use_stderr()
                || e.kind() == clap::error::ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand =>
        {
            e.exit()
        }
        Err(e) => {
            let suggestion = subcommand_meant(&e);
            say_on_stderr(&one_line_usage_error(
                &e.render().to_string(),
                suggestion.as_deref(),
            ));
            return ExitCode::from(2);
        }
    };
    match cli.command.execute() {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of stdout went away (`| head`): the work is done and nobody is left to
        // read an error line, so exit quietly with 0, as ripgrep does (a shell's `cat`, killed
        // by SIGPIPE, gives 141; Rust ignores SIGPIPE, and the answer was only cut short).
        Err(err)
            if err.chain().any(|c| {
                c.downcast_ref::<stdout::StdoutError>()
                    .is_some_and(stdout::StdoutError::is_closed_pipe)
            }) =>
        {
            ExitCode::SUCCESS
        }
        Err(err) => {
            let code = exit_code(&err);
            say_on_stderr(&logging::error_line(&one_line(&err), code));
            ExitCode::from(code)
        }
    }
}

/// The command's last line on stderr. `eprintln!` panics when stderr is a closed pipe (exit 101
/// instead of the error's code); with nobody left to read it, the exit code is the answer.
fn say_on_stderr(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// clap's usage error on one line, as every other error: its lines joined (the usage kept, as
/// it says what is missing), without the blank lines and the "For more information" one. With
/// `suggestion` (a mistyped subcommand's, [`subcommand_meant`]) the first line asks "did you
/// mean `run`?" in place of clap's own tip.
fn one_line_usage_error(text: &str, suggestion: Option<&str>) -> String {
    let mut parts: Vec<String> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("For more information"))
        .filter(|l| suggestion.is_none() || !l.starts_with("tip: a similar subcommand exists"))
        .map(str::to_string)
        .collect();
    if let (Some(meant), Some(first)) = (suggestion, parts.first_mut()) {
        first.push_str(&format!("; did you mean `{meant}`?"));
    }
    format!(
        "{} (--help for more)",
        parts.join(" ").replace(" Usage:", "; usage:")
    )
}

/// The subcommand a mistyped one most likely meant: clap's suggestion, or else the one a
/// single edit away, a swap of two neighbouring letters counted as one (clap's similarity
/// measure suggests nothing for short names: `rnu` and `rn` got no hint of `run`).
fn subcommand_meant(e: &clap::Error) -> Option<String> {
    use clap::CommandFactory;
    use clap::error::{ContextKind, ContextValue};
    if e.kind() != clap::error::ErrorKind::InvalidSubcommand {
        return None;
    }
    if let Some(ContextValue::Strings(names)) = e.get(ContextKind::SuggestedSubcommand) {
        return names.first().cloned();
    }
    let Some(ContextValue::String(typed)) = e.get(ContextKind::InvalidSubcommand) else {
        return None;
    };
    cli::Cli::command()
        .get_subcommands()
        .map(|c| (strsim::osa_distance(typed, c.get_name()), c.get_name()))
        .filter(|&(distance, _)| distance <= 1)
        .min()
        .map(|(_, name)| name.to_string())
}

/// Joins the context chain into one line: "reading job a.toml: a.toml:3: unknown field ...".
fn one_line(err: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in err.chain() {
        let s = cause.to_string();
        if !parts.iter().any(|p| p.contains(&s)) {
            parts.push(s);
        }
    }
    parts.join(": ").replace('\n', " ")
}

fn exit_code(err: &anyhow::Error) -> u8 {
    use isostream_pipeline::RunError;
    for cause in err.chain() {
        if let Some(run) = cause.downcast_ref::<RunError>() {
            return match run {
                RunError::Cancelled | RunError::Interrupted { .. } => 130,
                RunError::Config(_)
                | RunError::Volume(_)
                | RunError::EmptySurface { .. }
                | RunError::ClassicalOverBudget { .. }
                | RunError::IndexLimit { .. }
                | RunError::SliceMemory { .. }
                // The output's folder cannot be created or written: a job (or a command) to fix.
                | RunError::OutputFolder { .. }
                // The command asks for what cannot be done: a flag to add (`--resume` or
                // `--restart`), or a resume of a job or input that changed since, or of a
                // checkpoint that is truncated, corrupt or not one, or whose temporary files are
                // gone or cut short (`--restart` is the fix in every case; a checkpoint that
                // could not be written is a failure, 1).
                | RunError::CheckpointFound { .. }
                | RunError::FinishedFound { .. }
                | RunError::Checkpoint { .. }
                | RunError::ResumeMismatch { .. }
                | RunError::InputChanged { .. } => 2,
                _ => 1,
            };
        }
        if cause
            .downcast_ref::<isostream_pipeline::ConfigError>()
            .is_some()
        {
            return 2;
        }
        // check, convert, measure: a mesh that cannot be read is bad input (2); failing to
        // write the converted file is not (1).
        if let Some(e) = cause.downcast_ref::<isostream_smesh::SmeshError>() {
            return match e {
                isostream_smesh::SmeshError::Interrupted { .. } => 130,
                isostream_smesh::SmeshError::Io { source, .. }
                    if !matches!(
                        source.kind(),
                        std::io::ErrorKind::NotFound
                            | std::io::ErrorKind::IsADirectory
                            // Text that is not UTF-8 (an SMA or OBJ line): bad input.
                            | std::io::ErrorKind::InvalidData
                    ) =>
                {
                    1
                }
                _ => 2,
            };
        }
        // serve: a configuration to fix (flags, config file) is 2, so that a supervisor can
        // tell it from a failure worth retrying.
        if let Some(e) = cause.downcast_ref::<isostream_service::ServiceError>() {
            return if e.is_bad_config() { 2 } else { 1 };
        }
        // report: a run summary or measure file missing or not one is bad input (2).
        if let Some(e) = cause.downcast_ref::<isostream_report::ReportError>() {
            return match e {
                isostream_report::ReportError::Read { .. }
                | isostream_report::ReportError::NotRun { .. }
                | isostream_report::ReportError::NotMeasure { .. }
                | isostream_report::ReportError::OtherMesh { .. }
                | isostream_report::ReportError::OverInput { .. } => 2,
                _ => 1,
            };
        }
        if cause.downcast_ref::<cli::UsageError>().is_some() {
            return 2;
        }
        // measure: a job other than the one that made the mesh is bad input.
        if cause.downcast_ref::<measure_cmd::OtherJob>().is_some() {
            return 2;
        }
        if let Some(e) = cause.downcast_ref::<isostream_measure::MeasureError>() {
            return match e {
                isostream_measure::MeasureError::Volume(_)
                | isostream_measure::MeasureError::VertexIndex { .. }
                | isostream_measure::MeasureError::EmptyOutput
                | isostream_measure::MeasureError::OffVolume(_)
                | isostream_measure::MeasureError::Unsampleable(_)
                | isostream_measure::MeasureError::EmptySurface => 2,
                _ => 1,
            };
        }
    }
    1
}
