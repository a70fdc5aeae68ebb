//! The terminal progress bar of `isostream run` (the pass, slabs, rate, ETA, faces, RSS), and a log writer
//! that prints log lines above the bar instead of through it.

use std::io::Write;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{HumanDuration, ProgressBar, ProgressDrawTarget, ProgressStyle};
use isostream_pipeline::{Done, Pass, Progress, eta_seconds};

/// The bar on screen, if any: log lines are written around it.
static SHOWN: Mutex<Option<ProgressBar>> = Mutex::new(None);

fn shown() -> std::sync::MutexGuard<'static, Option<ProgressBar>> {
    SHOWN.lock().unwrap_or_else(|e| e.into_inner())
}

/// The bar of a run, and the pass it shows (`None` before the first report).
pub struct Bar {
    bar: ProgressBar,
    pass: Mutex<Option<PassStart>>,
}

/// The pass the bar shows, from its beginning (reported before its first slab): its rate and
/// ETA pace from there.
struct PassStart {
    pass: Pass,
    at: Instant,
}

/// A bar on stderr, registered so that log lines go above it. Its clock counts from the job's
/// start; its rate and ETA are those of the pass it shows, as the `progress` log lines' (the
/// slabs done since the pass began, and `eta_seconds`: the run's follows its faces when a first
/// pass counted them). indicatif's own rate paced by the jump to the first slab: a first pass
/// began at "35071.0 slabs/s".
pub fn bar() -> Bar {
    // Hidden until the first report says which pass it is and how many slabs it has: a log
    // line drew it before as "slab 0/1" (length 1, as 0 would show 100 %).
    let bar = ProgressBar::with_draw_target(Some(1), ProgressDrawTarget::hidden());
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} {prefix}[{bar:30}] {percent:>3}% slab {pos}/{len} {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
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
    let first_report = pass.is_none();
    let begins = pass.as_ref().is_none_or(|s| s.pass != p.pass);
    bar.set_length(p.slabs_total);
    bar.set_position(p.slabs_done);
    if begins {
        bar.set_prefix(match p.pass {
            Pass::First => "first pass ",
            Pass::Run => "",
        });
        // A pass's rate and ETA count from its beginning: with the time before it (the first
        // pass) a 78 s run promised its end in 15 minutes.
        *pass = None;
    }
    let start = pass.get_or_insert_with(|| PassStart {
        pass: p.pass,
        at: Instant::now(),
    });
    let pace = pace_text(start.at.elapsed().as_secs_f64(), p);
    let rss = isostream_pipeline::current_rss_bytes().map_or(String::new(), |b| {
        format!(", RSS {:.0} MiB", b as f64 / (1 << 20) as f64)
    });
    bar.set_message(match p.pass {
        // Its faces are counted at its end.
        Pass::First => format!("{pace} | counting faces{rss}"),
        Pass::Run => format!(
            "{pace} | faces in {} out {} resident {}{rss}",
            p.faces_in, p.faces_out, p.resident_faces
        ),
    });
    if first_report {
        bar.set_draw_target(ProgressDrawTarget::stderr());
        bar.tick();
    }
}

/// The rate and ETA of a pass that began `seconds` ago, at `p`: the slabs done since it began (a
/// resumed run's jump to its checkpoint's slab is not work done), `?` for both before one is.
fn pace_text(seconds: f64, p: &Progress) -> String {
    let slabs = Done {
        start: p.slabs_at_start,
        now: p.slabs_done,
        total: p.slabs_total,
    };
    let rate = slabs
        .per_second(seconds)
        .map_or_else(|| "?".into(), |r| format!("{r:.1}"));
    let eta = eta_text(eta_seconds(seconds, slabs, p.faces_done()));
    format!("{rate} slabs/s ETA {eta}")
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

    /// A pass reported before its first slab shows neither a rate nor an ETA; a resumed run's
    /// checkpoint slab is not paced by.
    #[test]
    fn no_rate_before_a_slab() {
        let begun = Progress::fresh(Pass::First, 255);
        assert_eq!(pace_text(1e-5, &begun), "? slabs/s ETA ?");
        let resumed = Progress {
            pass: Pass::Run,
            slabs_done: 100,
            slabs_at_start: 100,
            ..begun
        };
        assert_eq!(pace_text(1e-5, &resumed), "? slabs/s ETA ?");
        let one = Progress {
            slabs_done: 101,
            ..resumed
        };
        assert_eq!(pace_text(2.0, &one), "0.5 slabs/s ETA 5m");
    }

    #[test]
    fn no_eta_before_a_pace() {
        assert_eq!(eta_text(None), "?");
        assert_eq!(eta_text(Some(0.0)), "0s");
        assert_eq!(eta_text(Some(120.0)), "2m");
    }
}
