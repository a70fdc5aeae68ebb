//! `run`, `validate`, `convert`, `check`.

use std::io::IsTerminal;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::Context;
use isostream_pipeline::{JobConfig, LogFormat, Progress, RunSummary};

pub fn validate(job_path: &Path) -> anyhow::Result<()> {
    let job = JobConfig::load(job_path)?;
    // The input file (exists, size matches dims and type), the attributes' files (on the iso
    // volume's grid) and the output format's index limit, as `run` checks them.
    let mut source = isostream_pipeline::preflight(&job)?;
    let grid = source.grid();
    crate::stdout::line(format_args!(
        "{}: ok: {} ({} x {} x {} voxels), iso {}, mode {}{}, output {}",
        job_path.display(),
        source.describe(),
        grid.dims[0],
        grid.dims[1],
        grid.dims[2],
        job.extract.iso,
        job.simplify.mode,
        job.output
            .faces
            .map_or(String::new(), |f| format!(" to {f} faces")),
        job.output.path.display()
    ))?;
    if let Some(w) = isostream_pipeline::orientation_warning(source.as_ref()) {
        crate::stdout::line(format_args!("{}: warning: {w}", job_path.display()))?;
    }
    // `run` would refuse to start over a checkpoint without --resume or --restart: said here,
    // with which of the two it can take, as a note (the job itself is fine). While a run of
    // this output is live, the checkpoint is its own, not an interrupted run's: `run` is
    // refused until it ends, and that is the note.
    let note = match isostream_pipeline::output_in_use(&job.output.path) {
        Some(lock) => Some(format!(
            "a run of this output is in progress (it holds {}); `run` is refused until it ends",
            lock.display()
        )),
        None => isostream_pipeline::checkpoint_note(&job, source.as_mut())?,
    };
    if let Some(note) = note {
        crate::stdout::line(format_args!("{}: note: {note}", job_path.display()))?;
    }
    Ok(())
}

pub fn run(
    job_path: &Path,
    quiet: bool,
    clean_stale: bool,
    start: isostream_pipeline::Start,
) -> anyhow::Result<()> {
    let job = JobConfig::load(job_path).inspect_err(|_| {
        // Read but not valid (a bad value, not bad TOML): its error in the format its `[log]`
        // asks for, as every later error is.
        let log = std::fs::read_to_string(job_path)
            .ok()
            .and_then(|text| JobConfig::parse(&text, job_path).ok())
            .map(|parsed| parsed.log);
        if let Some(log) = log {
            crate::logging::init(&log, None);
        }
    })?;
    crate::logging::init(&job.log, None);

    // Ctrl-C, SIGTERM and SIGHUP (ctrlc's `termination` feature) all stop the run the same way:
    // every stage stops, the temporary file is removed (kept, with the checkpoint, once a
    // checkpoint was saved: `--resume` continues), exit code 130.
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let cancel = Arc::clone(&cancel);
        ctrlc::set_handler(move || cancel.store(true, Ordering::Relaxed))
            .context("cannot install the Ctrl-C / SIGTERM / SIGHUP handler")?;
        // Under `nohup` a closed terminal does not stop the run.
        crate::keep_hangup_ignored();
    }
    // Held until the run ends: a second job on the same output is refused, and temporary files
    // of this output found now cannot belong to a live run.
    let _lock = isostream_pipeline::lock_output(&job.output.path)?;
    stale_files(&job.output.path, clean_stale, "run")?;
    // A bar for a person at a terminal; JSON logs are for machines, which get the periodic
    // `progress` lines instead.
    let bar = (!quiet && std::io::stderr().is_terminal() && job.log.format != LogFormat::Json)
        .then(crate::progress::bar);
    let observer = |p: &Progress| {
        if let Some(bar) = &bar {
            crate::progress::update(bar, p);
        }
    };
    let summary = isostream_pipeline::run_from(&job, job_path, start, &cancel, &observer);
    if let Some(bar) = &bar {
        crate::progress::finish(bar);
    }
    let summary = summary?;
    // The output is complete by now: the error says so, or it reads like a failed run.
    report(&summary).with_context(|| {
        format!(
            "{}: written, but not its summary line",
            normalised(&summary.output).display()
        )
    })?;
    Ok(())
}

/// Reports (or with `--clean-stale` removes) what interrupted runs or conversions of this output
/// left behind; `command` (`run` or `convert`) names the command whose `--clean-stale` removes
/// them. Called with the output's lock held, so no live process owns what it finds.
fn stale_files(output: &Path, clean: bool, command: &str) -> anyhow::Result<()> {
    let mut stale = isostream_pipeline::stale_temp_files(output);
    // Checkpoints a killed run was still writing (`.NAME.ckpt.XXXXXX.tmp`) hold nothing a run
    // can use (only a finished checkpoint is resumed from) and nothing else refers to them, and
    // this run holds the output's lock, so no live run owns them: removed without asking. With
    // `every_slabs = 1` each `kill -9` left four or five, 90 MB after four kills.
    let partial = format!(
        ".{}.ckpt.",
        output.file_name().unwrap_or_default().to_string_lossy()
    );
    stale.retain(|p| {
        let unfinished = p
            .file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with(&partial));
        !(unfinished && std::fs::remove_file(p).is_ok())
    });
    if stale.is_empty() {
        return Ok(());
    }
    let names: Vec<String> = stale.iter().map(|p| p.display().to_string()).collect();
    if clean {
        for p in &stale {
            std::fs::remove_file(p)
                .with_context(|| format!("{}: cannot remove stale temporary file", p.display()))?;
        }
        tracing::info!(files = %names.join(", "), "removed stale temporary files");
    } else {
        tracing::warn!(
            "{} stale temporary file(s) of {} left by an interrupted run or conversion: {}; `isostream {command} --clean-stale` removes them",
            stale.len(),
            output.display(),
            names.join(", ")
        );
    }
    Ok(())
}

/// The output path as the user would type it: absolute, without `.` or `..` components.
fn normalised(path: &Path) -> std::path::PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}

/// The `job done` line: numbers as numbers (a JSON log reader got `"seconds":"6.443"`), rounded
/// to what is worth reading (seconds to the millisecond, MiB to a tenth); an unknown peak RSS is
/// left out rather than logged as NaN. Then the one line on stdout.
fn report(s: &RunSummary) -> Result<(), crate::stdout::StdoutError> {
    let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
    let ms = |x: f64| (x * 1000.0).round() / 1000.0;
    tracing::info!(
        voxels = s.voxels,
        faces_extracted = s.faces_extracted,
        faces_written = s.faces_written,
        seconds = ms(s.seconds),
        read_s = ms(s.stage_seconds.read),
        extract_s = ms(s.stage_seconds.extract),
        detect_s = ms(s.stage_seconds.detect),
        // Only when the job prunes (`[simplify] min_component_faces`): its stage between the
        // detector and the simplifier, left out of the line before.
        prune_s = s.stage_seconds.prune.map(ms),
        simplify_s = ms(s.stage_seconds.simplify),
        // A cascade's second simplifier: it is the busiest stage of many runs. Left out of a
        // one-stage run, where a 0.0 read as a stage that ran (a user trial).
        simplify_second_s = s
            .simplify_stages
            .is_some()
            .then(|| ms(s.stage_seconds.simplify_second)),
        write_s = ms(s.stage_seconds.write),
        peak_rss_mib = s.peak_rss_bytes.map(|b| (mib(b) * 10.0).round() / 10.0),
        peak_resident_faces = s.peak_resident_faces,
        "job done"
    );
    let pruned = s.prune.map_or(String::new(), |p| {
        format!(
            " ({} faces in {} components under {} faces pruned)",
            p.faces_pruned, p.components_pruned, p.min_component_faces
        )
    });
    crate::stdout::line(format_args!(
        "{}: {} -> {} faces{pruned} in {:.2} s, peak RSS {:.1} MiB",
        normalised(&s.output).display(),
        s.faces_extracted,
        s.faces_written,
        s.seconds,
        s.peak_rss_bytes.map(mib).unwrap_or(f64::NAN)
    ))
}

/// `isostream report`: the run summary (and a measure report) as one HTML page.
pub fn report_page(run: &Path, output: &Path, measure: Option<&Path>) -> anyhow::Result<()> {
    // Before any work: a device, FIFO or socket at `-o` is refused (exit 2), a link followed.
    isostream_smesh::check_replaceable(output)?;
    let same = |input: &Path| isostream_pipeline::one_file(input, output);
    if same(run) || measure.is_some_and(same) {
        return Err(isostream_report::ReportError::OverInput {
            path: output.to_path_buf(),
        }
        .into());
    }
    let summary = isostream_report::Run::load(run)?;
    let measure = match measure {
        Some(path) => {
            let m = isostream_report::Measure::load(path)?;
            m.check_of(path, &summary, run)?;
            Some(m)
        }
        None => None,
    };
    let page = isostream_report::html(&summary, measure.as_ref())?;
    isostream_report::write(output, &page)?;
    crate::stdout::line(format_args!(
        "{}: report of {} ({} bytes)",
        normalised(output).display(),
        run.display(),
        page.len()
    ))?;
    Ok(())
}

/// `convert`'s output options from its flags; a flag the output's format has no use for is a
/// usage error (exit 2), not silently ignored.
pub fn convert_options(
    output: &Path,
    ascii: bool,
    normals: bool,
) -> anyhow::Result<isostream_smesh::ConvertOptions> {
    use isostream_smesh::Format;
    let format = Format::from_path(output)?;
    for (set, flag, wants) in [
        (ascii, "--ascii", Format::Ply),
        (normals, "--normals", Format::Glb),
    ] {
        if set && format != wants {
            return Err(crate::cli::UsageError(format!(
                "{}: {flag} applies to a {} output only, not {}; drop {flag} or change the output's extension",
                output.display(),
                format!("{wants:?}").to_uppercase(),
                format!("{format:?}").to_uppercase()
            ))
            .into());
        }
    }
    Ok(isostream_smesh::ConvertOptions {
        ply_encoding: match ascii {
            true => isostream_smesh::PlyEncoding::Ascii,
            false => isostream_smesh::PlyEncoding::BinaryLittleEndian,
        },
        normals,
    })
}

pub fn convert(
    input: &Path,
    output: &Path,
    options: &isostream_smesh::ConvertOptions,
    json: bool,
    clean_stale: bool,
) -> anyhow::Result<()> {
    // Before any work (the lock, the input): a device, FIFO or socket at the output is refused
    // (exit 2), a link followed.
    isostream_smesh::check_replaceable(output)?;
    // Ctrl-C, SIGTERM and SIGHUP stop a conversion as they stop a run: its temporary file
    // removed, exit code 130 (killed by the signal, it was left behind).
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = Arc::clone(&stop);
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("cannot install the Ctrl-C / SIGTERM / SIGHUP handler")?;
        crate::keep_hangup_ignored();
    }
    // The same lock as a run's: a run and a conversion (or two conversions) never write one
    // file at once, and temporary files of this output found now are stale. Taking it creates
    // the output's folder when missing, as for a run.
    let _lock = isostream_pipeline::lock_output(output).map_err(|e| match e {
        isostream_pipeline::RunError::Locked { lock, .. } => anyhow::anyhow!(
            "{}: another isostream run or conversion is writing this file (it holds {}); wait for it to finish or convert to another file",
            output.display(),
            lock.display()
        ),
        other => other.into(),
    })?;
    // Text logs at the default level (a conversion has no job file to configure them): the
    // stale files' notice is a warning like a run's.
    crate::logging::init(&isostream_pipeline::LogConfig::default(), None);
    stale_files(output, clean_stale, "convert")?;
    let stats = isostream_smesh::convert_until(input, output, options, &stop)?;
    let w = &stats.written;
    if json {
        let v = serde_json::json!({
            "input": input,
            "output": normalised(output),
            "input_format": format!("{:?}", stats.input),
            "output_format": format!("{:?}", stats.output),
            "vertices": w.vertices,
            "triangles": w.triangles,
            "bytes": w.bytes,
            "max_active_vertices": w.max_active_vertices,
            "dropped_vertices": stats.dropped_vertices,
            "dropped_triangles": stats.dropped_triangles,
        });
        crate::stdout::line(v)?;
        return Ok(());
    }
    let mut line = format!(
        "{} -> {}: {} vertices, {} triangles, {} bytes written",
        input.display(),
        normalised(output).display(),
        w.vertices,
        w.triangles,
        w.bytes
    );
    if stats.output.is_streaming() {
        line.push_str(&format!(
            ", stream width {} vertices",
            w.max_active_vertices
        ));
    }
    if stats.dropped_triangles > 0 {
        line.push_str(&format!(
            "; {} triangles that use a vertex twice (no area) were dropped",
            stats.dropped_triangles
        ));
    }
    if stats.dropped_vertices > 0 {
        line.push_str(&format!(
            "; {} vertices no triangle uses were dropped",
            stats.dropped_vertices
        ));
    }
    crate::stdout::line(line)?;
    Ok(())
}

pub fn check(mesh: &Path, json: bool) -> anyhow::Result<()> {
    let r = match isostream_smesh::validate(mesh) {
        Ok(r) => r,
        Err(e) => {
            // A script reading stdout gets an answer too, not only the error line on stderr.
            // The mesh's error is the answer: a failure to write this one is not reported over it.
            if json {
                let v = serde_json::json!({ "path": mesh, "valid": false, "error": e.to_string() });
                let _ = crate::stdout::line(v);
            }
            return Err(e.into());
        }
    };
    if json {
        let v = serde_json::json!({
            "path": mesh,
            "valid": true,
            "format": format!("{:?}", r.format),
            "vertices": r.vertices,
            "triangles": r.triangles,
            "max_active_vertices": r.max_active_vertices,
            "max_triangle_skip": r.max_triangle_skip,
            "attributes": r.header.attribute_names,
            "comments": r.header.comments,
        });
        crate::stdout::line(v)?;
        return Ok(());
    }
    let format = format!("{:?}", r.format).to_uppercase();
    let mut line = format!(
        "{}: valid {format} streaming mesh: {} vertices, {} triangles, stream width {} vertices, farthest triangle reach {}",
        mesh.display(),
        r.vertices,
        r.triangles,
        r.max_active_vertices,
        r.max_triangle_skip
    );
    if !r.header.attribute_names.is_empty() {
        line.push_str(&format!(
            ", attributes {}",
            r.header.attribute_names.join(", ")
        ));
    }
    crate::stdout::line(line)?;
    Ok(())
}
