//! The HTML page around the plots: a table of the run's figures, its warnings, then the plots,
//! each in a `<figure id=...>` (`memory`, `faces`, `stages`, `min-angles`, `distances-*`).

use std::fmt::Write as _;

use crate::input::{Measure, Run};
use crate::{ReportError, plots};

/// Stages in pipeline order; any other stage a summary names follows, alphabetically.
const STAGE_ORDER: [&str; 6] = ["read", "extract", "detect", "prune", "simplify", "write"];

const STYLE: &str = "body{font:14px/1.4 system-ui,sans-serif;margin:2em;color:#222;max-width:800px}\
h1{font-size:1.3em}table{border-collapse:collapse}td,th{text-align:left;padding:3px 10px;\
border-bottom:1px solid #ddd}figure{margin:1.5em 0}figcaption{color:#555;font-size:.9em}\
.warn{color:#a04000}svg{max-width:100%;height:auto}";

/// The whole page for a run and, when given, its measure report.
pub fn html(run: &Run, measure: Option<&Measure>) -> Result<String, ReportError> {
    let name = run.output.file_name().map_or_else(
        || run.output.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let mut s = String::new();
    let _ = write!(
        s,
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>isostream report: {}</title>\
         <style>{STYLE}</style></head><body>\n<h1>isostream run: {}</h1>\n",
        escape(&name),
        escape(&name)
    );
    summary_table(&mut s, run, measure);
    for w in &run.warnings {
        let _ = writeln!(s, "<p class=\"warn\">warning: {}</p>", escape(w));
    }
    match run.series.as_ref().filter(|t| !t.points.is_empty()) {
        Some(series) => {
            let per_point = if series.stride > 1 {
                format!(" Each point stands for {} slabs (the series keeps at most {} points): lines show the largest value of its slabs, the band the range.", series.stride, isostream_pipeline::MAX_SERIES_POINTS)
            } else {
                String::new()
            };
            figure(
                &mut s,
                "memory",
                &plots::memory(&series.points)?,
                &format!("Resident set size from the OS and faces resident in the simplifier at the end of each slab: the faces rise as slabs arrive and drop when the simplifier decimates or retires (Hou and Chen, Fig. 5).{per_point}"),
            );
            figure(
                &mut s,
                "faces",
                &plots::faces(&series.points)?,
                "Full-resolution faces extracted and simplified faces written per slab (left axis), and the faces resident in the simplifier at its end (right axis).",
            );
        }
        None => s.push_str(
            "<p>This summary has no time series (written by an older isostream): no sweep plots.</p>\n",
        ),
    }
    figure(
        &mut s,
        "stages",
        &plots::stage_seconds(&stages(run))?,
        "Seconds each stage was busy (time blocked on its channels excluded); the stages run at the same time, each on its own thread.",
    );
    if let Some(m) = measure {
        measure_figures(&mut s, m)?;
    }
    let _ = write!(
        s,
        "<p><small>made by isostream {} (<code>isostream report</code>)</small></p>\n</body></html>\n",
        env!("CARGO_PKG_VERSION")
    );
    Ok(s)
}

fn summary_table(s: &mut String, run: &Run, measure: Option<&Measure>) {
    let mib = |b: u64| format!("{:.1} MiB", b as f64 / (1024.0 * 1024.0));
    let [nx, ny, nz] = run.dims;
    let mut rows = vec![
        ("input", run.input.clone()),
        (
            "grid",
            format!("{nx} x {ny} x {nz} = {} voxels", run.voxels),
        ),
        ("iso value, mode", format!("{}, {}", run.iso, run.mode)),
        ("output", run.output.display().to_string()),
        (
            "faces",
            format!(
                "{} extracted{} -> {} written{} ({} vertices)",
                run.faces_extracted,
                run.prune.map_or(String::new(), |p| format!(
                    ", {} in {} components under {} faces pruned",
                    p.faces_pruned, p.components_pruned, p.min_component_faces
                )),
                run.faces_written,
                run.target_faces
                    .map_or(String::new(), |t| format!(" (target {t})")),
                run.vertices_written
            ),
        ),
        ("time", time(run)),
        (
            "peak memory",
            format!(
                "{} RSS, {} faces resident",
                run.peak_rss_bytes.map_or("unknown".into(), mib),
                run.peak_resident_faces
            ),
        ),
    ];
    if let Some(m) = measure {
        let q = &m.quality;
        rows.push((
            "measured mesh",
            format!(
                "{} triangles, {}, Euler characteristic {}",
                q.triangles,
                if q.closed {
                    "closed manifold"
                } else {
                    "NOT a closed manifold"
                },
                q.euler
            ),
        ));
        if let Some(d) = &m.distances {
            let bound = at_least(d);
            rows.push((
                "distance to the full surface",
                format!(
                    "RMS {bound}{:.4} %, Hausdorff {bound}{:.4} %{} of the diagonal (full -> output mean {:.4}, output -> full mean {bound}{:.4}){}",
                    d.rms_pct,
                    d.hausdorff_pct,
                    d.p999_pct
                        .map(|p| format!(", 99.9 % of the samples within {bound}{p:.4} %"))
                        .unwrap_or_default(),
                    d.full_to_output.mean,
                    d.output_to_full.mean,
                    match clipped_note(d) {
                        note if note.is_empty() => note,
                        note => format!("; {note}"),
                    }
                ),
            ));
        }
    }
    s.push_str("<table>\n");
    for (k, v) in rows {
        let _ = writeln!(s, "<tr><th>{k}</th><td>{}</td></tr>", escape(&v));
    }
    s.push_str("</table>\n");
}

/// "at least " before the distances of a measure report that counted output samples at its
/// search radius (an older version's: see `Distances::clipped_samples`).
fn at_least(d: &crate::input::Distances) -> &'static str {
    if d.clipped_samples > 0 {
        "at least "
    } else {
        ""
    }
}

/// Why [`at_least`] says so, and how to get exact values (empty when it does not).
fn clipped_note(d: &crate::input::Distances) -> String {
    if d.clipped_samples == 0 {
        return String::new();
    }
    format!(
        "{} output samples counted at the search radius {:.4}: lower bounds, measure again with this version for exact values",
        d.clipped_samples, d.max_distance
    )
}

fn measure_figures(s: &mut String, m: &Measure) -> Result<(), ReportError> {
    figure(
        s,
        "min-angles",
        &plots::histogram(
            "Minimum angle of each triangle",
            "degrees",
            &m.quality.min_angle_histogram,
            "min-angle",
        )?,
        "Triangles by their smallest angle (60 degrees: equilateral), from isostream measure.",
    );
    let Some(d) = &m.distances else {
        return Ok(());
    };
    for (id, title, dir, bound) in [
        (
            "distances-full-to-output",
            "Distance from the full-resolution surface to the output",
            &d.full_to_output,
            "",
        ),
        (
            "distances-output-to-full",
            "Distance from the output to the full-resolution surface",
            &d.output_to_full,
            at_least(d),
        ),
    ] {
        if dir.histogram.is_empty() {
            continue;
        }
        // The bins end at the search radius, so the last one holds any sample past it. An
        // older measure counted the output samples there at the radius (`clipped_note`); since
        // its second pass they are at their exact distances, which the figures above include.
        let past = if !bound.is_empty() {
            format!("; the last bin also holds the {}", clipped_note(d))
        } else if dir.hausdorff > d.max_distance {
            format!(
                "; the last bin also counts the samples farther than the search radius {:.4}, each measured at its exact distance (up to the Hausdorff distance)",
                d.max_distance
            )
        } else {
            String::new()
        };
        figure(
            s,
            id,
            &plots::histogram(title, "distance", &dir.histogram, "distance")?,
            &format!(
                "Samples by distance (mean {bound}{:.4}, RMS {bound}{:.4}, Hausdorff {bound}{:.4}{}){past}.",
                dir.mean,
                dir.rms,
                dir.hausdorff,
                dir.p999
                    .map(|p| format!(", 99.9 % within {bound}{p:.4}"))
                    .unwrap_or_default(),
            ),
        );
    }
    Ok(())
}

/// The run's time and rate. A resumed run's time is its last attempt's, so its rate counts
/// the voxels that attempt read (from its slab on), not the whole volume: 61 s of a resumed
/// run showed 2.2 Mvoxels/s for a volume most of which an earlier attempt had read.
fn time(run: &Run) -> String {
    let voxels = isostream_pipeline::voxels_from_slab(run.dims, run.resumed_at_slab);
    let rate = voxels as f64 / run.seconds.max(1e-9) / 1e6;
    match run.resumed_at_slab {
        None => format!("{:.2} s ({rate:.1} Mvoxels/s)", run.seconds),
        Some(slab) => format!(
            "{:.2} s, resumed at slab {slab} ({rate:.1} Mvoxels/s over the {voxels} voxels read since; an earlier attempt read the rest)",
            run.seconds
        ),
    }
}

fn stages(run: &Run) -> Vec<(String, f64)> {
    let mut out: Vec<(String, f64)> = STAGE_ORDER
        .iter()
        .filter_map(|n| run.stage_seconds.get(*n).map(|&v| (n.to_string(), v)))
        .collect();
    out.extend(
        run.stage_seconds
            .iter()
            .filter(|(k, _)| !STAGE_ORDER.contains(&k.as_str()))
            .map(|(k, &v)| (k.clone(), v)),
    );
    out
}

fn figure(s: &mut String, id: &str, svg: &str, caption: &str) {
    let _ = writeln!(
        s,
        "<figure id=\"{id}\">\n{svg}\n<figcaption>{}</figcaption></figure>",
        escape(caption)
    );
}

/// Text into HTML: the five characters that could open markup or end an attribute.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_json(series: bool) -> serde_json::Value {
        let mut v = serde_json::json!({
            "input": "sphere <64^3>", "dims": [64, 64, 64], "voxels": 262144, "iso": 0.0,
            "mode": "rate", "output": "/tmp/out/<x>.smb", "faces_extracted": 1000,
            "target_faces": 200, "faces_written": 201, "vertices_written": 103, "seconds": 0.5,
            "stage_seconds": {"read": 0.1, "extract": 0.2, "detect": 0.1, "simplify": 0.3,
                              "write": 0.01, "upsample": 0.05},
            "peak_rss_bytes": 30000000, "peak_resident_faces": 300,
            "warnings": ["rate target missed"], "unknown_future_field": 1
        });
        if series {
            v["series"] = serde_json::json!({"stride": 1, "points": [
                {"slab": 1, "slabs": 1, "voxels_done": 8192, "faces_in": 10, "faces_out": 0,
                 "resident_faces": 10, "resident_faces_min": 10, "rss_bytes": 1000000, "seconds": 0.1},
                {"slab": 2, "slabs": 1, "voxels_done": 12288, "faces_in": 30, "faces_out": 5,
                 "resident_faces": 25, "resident_faces_min": 25, "rss_bytes": null, "seconds": 0.2}]});
        }
        v
    }

    #[test]
    fn a_page_has_its_figures_and_escapes_text() {
        let run: Run = serde_json::from_value(run_json(true)).unwrap();
        let page = html(&run, None).unwrap();
        for id in ["memory", "faces", "stages"] {
            assert!(page.contains(&format!("<figure id=\"{id}\">")), "{id}");
        }
        assert!(page.contains("&lt;x&gt;.smb") && !page.contains("<x>"));
        assert!(page.contains("warning: rate target missed"));
        assert!(!page.contains("pruned"));
        let mut pruned = run_json(true);
        pruned["prune"] = serde_json::json!({"min_component_faces": 100, "components_pruned": 7,
            "faces_pruned": 90, "vertices_pruned": 50});
        let pruned: Run = serde_json::from_value(pruned).unwrap();
        let pruned_page = html(&pruned, None).unwrap();
        assert!(pruned_page.contains("1000 extracted, 90 in 7 components under 100 faces pruned"));
        // Pipeline order first, other stages after.
        let at = |n: &str| page.find(&format!("\n{n}\n</text>")).unwrap();
        assert!(at("read") < at("simplify") && at("write") < at("upsample"));
        // Self-contained: nothing to fetch (the SVG namespace URI is a name, not a resource).
        for fetches in ["<script", "<link", "src=", "href=", "url("] {
            assert!(!page.contains(fetches), "{fetches}");
        }
    }

    /// A resumed run's page said "time 0.50 s (0.5 Mvoxels/s)", the whole volume over the last
    /// attempt's time, and never said it was resumed.
    #[test]
    fn a_resumed_run_says_so_and_rates_the_voxels_it_read() {
        let run: Run = serde_json::from_value(run_json(true)).unwrap();
        assert!(html(&run, None).unwrap().contains("0.50 s (0.5 Mvoxels/s)"));
        let mut resumed = run_json(true);
        resumed["resumed_at_slab"] = serde_json::json!(48);
        let resumed: Run = serde_json::from_value(resumed).unwrap();
        let page = html(&resumed, None).unwrap();
        // 16 of 64 slices of 64 x 64 voxels in 0.5 s.
        assert!(
            page.contains(
                "0.50 s, resumed at slab 48 (0.1 Mvoxels/s over the 65536 voxels read since"
            ),
            "{page}"
        );
    }

    /// A measure report of a version before the second pass over the surface counted output
    /// samples at the search radius: the page showed its Hausdorff distance and 99.9 % figure
    /// as they were. It now says "at least", and why; a report without them says nothing.
    #[test]
    fn a_measure_that_counted_samples_at_the_radius_shows_lower_bounds() {
        let run: Run = serde_json::from_value(run_json(true)).unwrap();
        let measure = |clipped: Option<u64>| -> Measure {
            let directed = serde_json::json!({"mean": 0.5, "rms": 0.6, "hausdorff": 2.0,
                "p999": 2.0, "histogram": [[0.0, 9], [1.0, 1]]});
            let mut d = serde_json::json!({"full_to_output": directed,
                "output_to_full": directed, "max_distance": 2.0, "rms_pct": 1.0,
                "hausdorff_pct": 4.0, "p999_pct": 4.0});
            if let Some(c) = clipped {
                d["clipped_samples"] = c.into();
            }
            serde_json::from_value(serde_json::json!({"quality": {"triangles": 201,
                "closed": true, "euler": 2, "min_angle_histogram": [[0.0, 201]]},
                "distances": d}))
            .unwrap()
        };
        let page = html(&run, Some(&measure(Some(7)))).unwrap();
        assert!(
            page.contains(
                "Hausdorff at least 4.0000 %, 99.9 % of the samples within at least 4.0000 %"
            ),
            "{page}"
        );
        assert!(
            page.contains("7 output samples counted at the search radius 2.0000: lower bounds")
        );
        assert!(page.contains("Hausdorff at least 2.0000, 99.9 % within at least 2.0000"));
        assert!(page.contains("the last bin also holds the 7 output samples counted at the search radius 2.0000: lower bounds"));
        for exact in [measure(Some(0)), measure(None)] {
            let page = html(&run, Some(&exact)).unwrap();
            assert!(!page.contains("at least") && !page.contains("lower bound"));
        }
    }

    /// The distance histograms' bins end at the search radius. Since the measure's second pass
    /// the samples past it are at their exact distances (in the last bin): the caption says so
    /// when there are some, and says nothing of them when there are none (it said "the last
    /// bin also counts samples farther than the search radius" of every report).
    #[test]
    fn a_distance_caption_tells_of_samples_past_the_radius_only_when_there_are_some() {
        let run: Run = serde_json::from_value(run_json(true)).unwrap();
        let measure = |hausdorff: f64, far: u64| -> Measure {
            let directed = serde_json::json!({"mean": 0.5, "rms": 0.6, "hausdorff": hausdorff,
                "p999": 1.5, "histogram": [[0.0, 9], [1.0, 1]]});
            serde_json::from_value(serde_json::json!({"quality": {"triangles": 201,
                "closed": true, "euler": 2, "min_angle_histogram": [[0.0, 201]]},
                "distances": {"full_to_output": directed, "output_to_full": directed,
                "max_distance": 2.0, "rms_pct": 1.0, "hausdorff_pct": 4.0, "p999_pct": 4.0,
                "far_samples": far}}))
            .unwrap()
        };
        let within = html(&run, Some(&measure(1.8, 0))).unwrap();
        assert!(!within.contains("search radius"), "{within}");
        let past = html(&run, Some(&measure(5.0, 3))).unwrap();
        assert!(
            past.contains("the last bin also counts the samples farther than the search radius 2.0000, each measured at its exact distance"),
            "{past}"
        );
        assert!(!past.contains("at least") && !past.contains("lower bound"));
    }

    #[test]
    fn an_old_summary_gets_a_page_without_sweep_plots() {
        let run: Run = serde_json::from_value(run_json(false)).unwrap();
        let page = html(&run, None).unwrap();
        assert!(page.contains("no time series"));
        assert!(!page.contains("<figure id=\"memory\">"));
        assert!(page.contains("<figure id=\"stages\">"));
    }
}
