//! The terminal progress bar of `isostream run` (the pass, slabs, rate, ETA, faces, RSS), and a log writer
//! that prints log lines above the bar instead of through it.

use std::io::Write;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{HumanDuration, ProgressBar, ProgressState, ProgressStyle};
use isostream_pipeline::{Done, Pass, Progress, eta_seconds};

/// The bar on screen, if any: log lines are written around it.
static SHOWN: Mutex<Option<ProgressBar>> = Mutex::new(None);

fn shown() -> std::sync::MutexGuard<'static, Option<ProgressBar>> {
    SHOWN.lock().unwrap_or_else(|e| e.into_inner())
}

/// The bar of a run, and the pass it shows (`None` before the first slab).
pub struct Bar {
    bar: ProgressBar,
    pass: Mutex<Option<PassStart>>,
}

/// The pass the bar shows, from its first slab: its ETA paces from there.
struct PassStart {
    pass: Pass,
    at: Instant,
    slabs: u64,
    faces_in: u64,
}

/// A bar on stderr, registered so that log lines go above it. Its clock counts from the job's
/// start; its rate and ETA are those of the pass it shows, the ETA as the `progress` log lines'
/// (`eta_seconds`: the run's follows its faces when a first pass counted them, where indicatif's
/// follows the slabs).
pub fn bar() -> Bar {
    // Length 1 until the first slab says how many there are: 0 would show 100 %.
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} {prefix}[{bar:30}] {percent:>3}% slab {pos}/{len} {rate} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .with_key("rate", |s: &ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = write!(w, "{:.1} slabs/s", s.per_sec());
        })
        .progress_chars("=> "),
    );
    *shown() = Some(bar.clone());
    Bar {
        bar,
        pass: Mutex::new(None),
    }
}

pub fn update(bar: &Bar, p: &Progress) {
    let Bar { bar, pass } = bar;
    let mut pass = pass.lock().unwrap_or_else(|e| e.into_inner());
    let begins = pass.as_ref().is_none_or(|s| s.pass != p.pass);
    if begins {
        bar.set_prefix(match p.pass {
            Pass::First => "first pass ",
            Pass::Run => "",
        });
    }
    bar.set_length(p.slabs_total);
    bar.set_position(p.slabs_done);
    if begins {
        // A pass's rate and ETA count from its first slab: with the time before it (the first
        // pass) a 78 s run promised its end in 15 minutes, and a resumed run's jump to its
        // checkpoint's slab counted as slabs done.
        bar.reset_eta();
        *pass = None;
    }
    let start = pass.get_or_insert_with(|| PassStart {
        pass: p.pass,
        at: Instant::now(),
        slabs: p.slabs_done,
        faces_in: p.faces_in,
    });
    let slabs = Done {
        start: start.slabs,
        now: p.slabs_done,
        total: p.slabs_total,
    };
    let faces = p.faces_done().map(|f| Done {
        start: start.faces_in,
        ..f
    });
    let eta = eta_text(eta_seconds(start.at.elapsed().as_secs_f64(), slabs, faces));
    let rss = isostream_pipeline::current_rss_bytes().map_or(String::new(), |b| {
        format!(", RSS {:.0} MiB", b as f64 / (1 << 20) as f64)
    });
    bar.set_message(match p.pass {
        // Its faces are counted at its end.
        Pass::First => format!("ETA {eta} | counting faces{rss}"),
        Pass::Run => format!(
            "ETA {eta} | faces in {} out {} resident {}{rss}",
            p.faces_in, p.faces_out, p.resident_faces
        ),
    });
}

/// `?` until the pass has done something to pace by: indicatif's ETA showed `0s` then, at a
/// pass's first slab, as if it were about to end.
fn eta_text(eta_s: Option<f64>) -> String {
    eta_s.map_or_else(
        || "?".into(),
        |s| {
            format!(
                "{:#}",
                HumanDuration(Duration::from_secs_f64(s.clamp(0.0, 1e9)))
            )
        },
    )
}

pub fn finish(bar: &Bar) {
    shown().take();
    bar.bar.finish_and_clear();
}

/// stderr for tracing: each formatted line (tracing-subscriber writes one event in one call) is
/// printed with the bar hidden, then the bar is drawn again below it.
///
/// A line stderr refuses is dropped, not reported: the log's reader going away (`2>&1 | head`)
/// or its disk filling must not end a job whose mesh is still being made. tracing-subscriber
/// reported such a failure with `eprintln!`, which panicked on the closed pipe (exit 101, the
/// run aborted, `isostream serve` deaf to SIGTERM); there is nowhere left to report it.
pub struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let bar = shown().clone();
        let _ = match bar {
            Some(bar) => bar.suspend(|| std::io::stderr().write_all(buf)),
            None => std::io::stderr().write_all(buf),
        };
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let _ = std::io::stderr().flush();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_eta_before_a_pace() {
        assert_eq!(eta_text(None), "?");
        assert_eq!(eta_text(Some(0.0)), "0s");
        assert_eq!(eta_text(Some(120.0)), "2m");
    }
}
