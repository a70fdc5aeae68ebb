//! The plots, each one SVG text made with `plotters`' SVG backend: the memory over the sweep,
//! faces per slab, stage busy time, and histograms (minimum angles, distances).
//!
//! Every series is named in its chart's legend, so the SVG says what it shows (the tests look
//! for those names).

use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;

use isostream_pipeline::SeriesPoint;

use crate::ReportError;

const SIZE: (u32, u32) = (760, 340);
const RSS: RGBColor = RGBColor(0x1f, 0x6f, 0xb4);
const RESIDENT: RGBColor = RGBColor(0xe0, 0x7b, 0x10);
const FACES_IN: RGBColor = RGBColor(0x2e, 0x9d, 0x4f);
const FACES_OUT: RGBColor = RGBColor(0x8e, 0x44, 0xad);
const BARS: RGBColor = RGBColor(0x3a, 0x7b, 0xd5);
const FONT: &str = "sans-serif";

/// Series names, as they appear in the legends.
pub const RSS_LABEL: &str = "RSS (MiB)";
pub const RESIDENT_LABEL: &str = "resident faces";
pub const FACES_IN_LABEL: &str = "faces in per slab";
pub const FACES_OUT_LABEL: &str = "faces out per slab";
/// The faces plot's left axis (its right one is [`RESIDENT_LABEL`]).
pub const PER_SLAB_AXIS: &str = "faces per slab";

type DrawResult<T> = Result<T, Box<dyn std::error::Error>>;

/// Draws into an SVG string; `what` names the plot in an error.
fn svg(
    what: &'static str,
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> DrawResult<()>,
) -> Result<String, ReportError> {
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, SIZE).into_drawing_area();
        let drawn = root
            .fill(&WHITE)
            .map_err(Into::into)
            .and_then(|()| draw(&root))
            .and_then(|()| root.present().map_err(Into::into));
        drawn.map_err(|e| ReportError::Plot {
            plot: what,
            reason: e.to_string(),
        })?;
    }
    Ok(out)
}

/// A range that plotters can draw even when every value is 0.
fn upto(max: f64) -> std::ops::Range<f64> {
    0.0..if max > 0.0 { max * 1.05 } else { 1.0 }
}

/// The legend box, top left: every series is named in it.
fn legend<'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, CT>,
) -> DrawResult<()> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

fn legend_line(color: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
}

/// An axis label: whole numbers as such, others to three significant digits.
fn num(v: &f64) -> String {
    if v.fract() == 0.0 || v.abs() >= 100.0 {
        format!("{v:.0}")
    } else {
        let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 12) as usize;
        let text = format!("{v:.digits$}");
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

/// Memory over the sweep: RSS from the OS (left axis) and the simplifier's resident faces
/// (right axis; a band from the fewest to the most once points stand for several slabs). The
/// saw-tooth of Hou and Chen's Fig. 5 is the resident faces rising between retirements.
pub fn memory(points: &[SeriesPoint]) -> Result<String, ReportError> {
    svg("memory", |root| {
        let x = upto(points.last().map_or(0, |p| p.slab) as f64);
        let rss_max = points.iter().filter_map(|p| p.rss_bytes).max().unwrap_or(0);
        let resident_max = points.iter().map(|p| p.resident_faces).max().unwrap_or(0);
        let mut chart = ChartBuilder::on(root)
            .caption("Memory over the sweep", (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .right_y_label_area_size(70)
            .build_cartesian_2d(x.clone(), upto(mib(rss_max)))?
            .set_secondary_coord(x, upto(resident_max as f64));
        chart
            .configure_mesh()
            .x_desc("slab")
            .x_label_formatter(&num)
            .y_label_formatter(&num)
            .y_desc(RSS_LABEL)
            .draw()?;
        chart
            .configure_secondary_axes()
            .y_label_formatter(&num)
            .y_desc(RESIDENT_LABEL)
            .draw()?;
        if points.iter().any(|p| p.slabs > 1) {
            let band = points
                .iter()
                .map(|p| (p.slab as f64, p.resident_faces as f64))
                .chain(
                    points
                        .iter()
                        .rev()
                        .map(|p| (p.slab as f64, p.resident_faces_min as f64)),
                )
                .collect::<Vec<_>>();
            chart.draw_secondary_series(std::iter::once(Polygon::new(band, RESIDENT.mix(0.25))))?;
        }
        chart
            .draw_secondary_series(LineSeries::new(
                points
                    .iter()
                    .map(|p| (p.slab as f64, p.resident_faces as f64)),
                RESIDENT.stroke_width(2),
            ))?
            .label(RESIDENT_LABEL)
            .legend(legend_line(RESIDENT));
        chart
            .draw_series(LineSeries::new(
                points
                    .iter()
                    .filter_map(|p| Some((p.slab as f64, mib(p.rss_bytes?)))),
                RSS.stroke_width(2),
            ))?
            .label(RSS_LABEL)
            .legend(legend_line(RSS));
        legend(&mut chart)
    })
}

/// One point of the faces plot.
struct SlabFaces {
    slab: f64,
    faces_in: f64,
    faces_out: f64,
    resident: f64,
}

/// Picks one line of the faces plot out of a point.
type Column = fn(&SlabFaces) -> f64;

/// Per slab: faces extracted (in) and emitted (out), averaged over the slabs a point stands
/// for (left axis), and the faces resident at its end (right axis): on one axis the resident
/// faces (72 k on a long gyroid) flattened the per-slab lines (760) onto zero.
pub fn faces(points: &[SeriesPoint]) -> Result<String, ReportError> {
    let mut previous = (0, 0);
    let rows: Vec<SlabFaces> = points
        .iter()
        .map(|p| {
            let slabs = p.slabs.max(1) as f64;
            let row = SlabFaces {
                slab: p.slab as f64,
                faces_in: p.faces_in.saturating_sub(previous.0) as f64 / slabs,
                faces_out: p.faces_out.saturating_sub(previous.1) as f64 / slabs,
                resident: p.resident_faces as f64,
            };
            previous = (p.faces_in, p.faces_out);
            row
        })
        .collect();
    svg("faces", |root| {
        let x = upto(points.last().map_or(0, |p| p.slab) as f64);
        let per_slab_max = rows
            .iter()
            .map(|r| r.faces_in.max(r.faces_out))
            .fold(0.0, f64::max);
        let resident_max = rows.iter().map(|r| r.resident).fold(0.0, f64::max);
        let mut chart = ChartBuilder::on(root)
            .caption("Faces per slab", (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .right_y_label_area_size(70)
            .build_cartesian_2d(x.clone(), upto(per_slab_max))?
            .set_secondary_coord(x, upto(resident_max));
        chart
            .configure_mesh()
            .x_desc("slab")
            .x_label_formatter(&num)
            .y_label_formatter(&num)
            .y_desc(PER_SLAB_AXIS)
            .draw()?;
        chart
            .configure_secondary_axes()
            .y_label_formatter(&num)
            .y_desc(RESIDENT_LABEL)
            .draw()?;
        let per_slab: [(&str, RGBColor, Column); 2] = [
            (FACES_IN_LABEL, FACES_IN, |r| r.faces_in),
            (FACES_OUT_LABEL, FACES_OUT, |r| r.faces_out),
        ];
        for (label, color, value) in per_slab {
            chart
                .draw_series(LineSeries::new(
                    rows.iter().map(|r| (r.slab, value(r))),
                    color.stroke_width(2),
                ))?
                .label(label)
                .legend(legend_line(color));
        }
        chart
            .draw_secondary_series(LineSeries::new(
                rows.iter().map(|r| (r.slab, r.resident)),
                RESIDENT.stroke_width(2),
            ))?
            .label(RESIDENT_LABEL)
            .legend(legend_line(RESIDENT));
        legend(&mut chart)
    })
}

/// One bar per stage: its busy seconds (time blocked on channels excluded).
pub fn stage_seconds(stages: &[(String, f64)]) -> Result<String, ReportError> {
    svg("stage seconds", |root| {
        let y_max = stages.iter().map(|s| s.1).fold(0.0, f64::max);
        let names: Vec<String> = stages.iter().map(|s| s.0.clone()).collect();
        let mut chart = ChartBuilder::on(root)
            .caption("Stage busy seconds", (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5..stages.len().max(1) as f64 - 0.5, upto(y_max))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(stages.len().max(1))
            .x_label_formatter(&|x| {
                let i = x.round();
                if (x - i).abs() < 1e-6 && i >= 0.0 {
                    names.get(i as usize).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_label_formatter(&num)
            .y_desc("seconds")
            .draw()?;
        chart.draw_series(stages.iter().enumerate().map(|(i, (_, s))| {
            let x = i as f64;
            Rectangle::new([(x - 0.35, 0.0), (x + 0.35, *s)], BARS.filled())
        }))?;
        Ok(())
    })
}

/// Bars of a histogram of `(bin start, count)` pairs with bins of equal width.
pub fn histogram(
    title: &str,
    x_desc: &str,
    bins: &[(f64, u64)],
    what: &'static str,
) -> Result<String, ReportError> {
    let width = match bins {
        [a, b, ..] => b.0 - a.0,
        [a] => a.0.abs().max(1.0),
        [] => 1.0,
    };
    svg(what, |root| {
        let x_min = bins.first().map_or(0.0, |b| b.0);
        let x_max = bins.last().map_or(1.0, |b| b.0 + width);
        let y_max = bins.iter().map(|b| b.1).max().unwrap_or(0) as f64;
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(x_min..x_max, upto(y_max))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc(x_desc)
            .x_label_formatter(&num)
            .y_label_formatter(&num)
            .y_desc("count")
            .draw()?;
        chart.draw_series(bins.iter().map(|&(start, n)| {
            Rectangle::new(
                [
                    (start + 0.05 * width, 0.0),
                    (start + 0.95 * width, n as f64),
                ],
                BARS.filled(),
            )
        }))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A saw-tooth of `n` slabs: resident faces rise by 100 a slab and drop every 10 slabs.
    pub(crate) fn saw_tooth(n: u64) -> Vec<SeriesPoint> {
        (1..=n)
            .map(|slab| {
                let resident = 100 * (slab % 10) + 50;
                SeriesPoint {
                    slab,
                    slabs: 1,
                    voxels_done: slab * 64,
                    faces_in: slab * 1000,
                    faces_out: slab * 200,
                    resident_faces: resident,
                    resident_faces_min: resident,
                    rss_bytes: Some((20 << 20) + resident * 1024),
                    seconds: slab as f64 * 0.01,
                }
            })
            .collect()
    }

    /// The trimmed contents of every `<text>` element.
    pub(crate) fn texts(svg: &str) -> Vec<&str> {
        svg.split("<text")
            .skip(1)
            .filter_map(|t| Some(t[t.find('>')? + 1..t.find("</text>")?].trim()))
            .collect()
    }

    fn polylines(svg: &str) -> Vec<&str> {
        svg.split("<polyline").skip(1).collect()
    }

    fn points_in(polyline: &str) -> usize {
        let attr = polyline.split("points=\"").nth(1).unwrap();
        attr[..attr.find('"').unwrap()].split_whitespace().count()
    }

    #[test]
    fn memory_has_both_series_with_a_point_per_slab() {
        let svg = memory(&saw_tooth(40)).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..80]);
        let labels = texts(&svg);
        for label in [RSS_LABEL, RESIDENT_LABEL, "Memory over the sweep", "slab"] {
            assert!(labels.contains(&label), "{label} missing: {labels:?}");
        }
        // The two data lines (legend samples are paths, not polylines, in plotters' SVG).
        let data: Vec<_> = polylines(&svg)
            .into_iter()
            .filter(|p| points_in(p) == 40)
            .collect();
        assert_eq!(data.len(), 2, "{svg}");
    }

    #[test]
    fn decimated_series_draw_a_band() {
        let mut points = saw_tooth(8);
        points.iter_mut().for_each(|p| {
            p.slabs = 2;
            p.resident_faces_min = 10;
        });
        assert!(memory(&points).unwrap().contains("<polygon"));
        assert!(!memory(&saw_tooth(8)).unwrap().contains("<polygon"));
    }

    #[test]
    fn faces_are_per_slab_rates() {
        let svg = faces(&saw_tooth(30)).unwrap();
        for label in [FACES_IN_LABEL, FACES_OUT_LABEL, RESIDENT_LABEL] {
            assert!(svg.contains(label), "{label} missing");
        }
        assert_eq!(
            polylines(&svg)
                .iter()
                .filter(|p| points_in(p) == 30)
                .count(),
            3
        );
    }

    /// Resident faces a hundred times the per-slab counts (a long gyroid: 72 k and 760) leave
    /// the per-slab lines their own scale: on one axis they lay flat on zero, 3 pixels high.
    #[test]
    fn per_slab_faces_keep_their_own_scale_beside_the_resident_ones() {
        let points: Vec<SeriesPoint> = (1..=40u64)
            .map(|slab| {
                let mut p = saw_tooth(40)[slab as usize - 1];
                // 500 and 1,000 faces a slab in turn; 70 k and more resident.
                p.faces_in = (slab / 2) * 1500 + (slab % 2) * 500;
                p.faces_out = 0;
                p.resident_faces = 70_000 + 100 * slab;
                p
            })
            .collect();
        let svg = faces(&points).unwrap();
        let labels = texts(&svg);
        for label in [PER_SLAB_AXIS, RESIDENT_LABEL] {
            assert!(labels.contains(&label), "{label} missing: {labels:?}");
        }
        // Drawn in order: in, out, resident.
        let lines: Vec<&str> = polylines(&svg)
            .into_iter()
            .filter(|p| points_in(p) == 40)
            .collect();
        let height = |polyline: &str| {
            let attr = polyline.split("points=\"").nth(1).unwrap();
            let ys: Vec<f64> = attr[..attr.find('"').unwrap()]
                .split_whitespace()
                .map(|xy| xy.split(',').nth(1).unwrap().parse().unwrap())
                .collect();
            ys.iter().fold(f64::MIN, |a, &b| a.max(b)) - ys.iter().fold(f64::MAX, |a, &b| a.min(b))
        };
        // Half the plot's height and more between 500 and 1,000 faces.
        assert!(height(lines[0]) > 100.0, "{}", height(lines[0]));
        assert_eq!(lines.len(), 3, "{svg}");
    }

    #[test]
    fn empty_and_flat_inputs_still_draw() {
        for svg in [
            memory(&[]).unwrap(),
            faces(&[]).unwrap(),
            stage_seconds(&[]).unwrap(),
            histogram("h", "x", &[], "h").unwrap(),
            histogram("h", "x", &[(0.0, 0), (1.0, 0)], "h").unwrap(),
        ] {
            assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        }
        let mut no_rss = saw_tooth(5);
        no_rss.iter_mut().for_each(|p| p.rss_bytes = None);
        assert!(memory(&no_rss).unwrap().contains(RESIDENT_LABEL));
    }

    #[test]
    fn axis_numbers_are_short() {
        assert_eq!(num(&45000.0), "45000");
        assert_eq!(num(&2.5), "2.5");
        assert_eq!(num(&0.05), "0.05");
        assert_eq!(num(&0.012345), "0.0123");
        assert_eq!(num(&150.25), "150");
    }

    #[test]
    fn one_bar_per_stage_and_bin() {
        let stages: Vec<(String, f64)> = ["read", "extract", "simplify"]
            .iter()
            .zip([0.5, 1.0, 4.0])
            .map(|(n, s)| (n.to_string(), s))
            .collect();
        let svg = stage_seconds(&stages).unwrap();
        let labels = texts(&svg);
        for name in ["read", "extract", "simplify"] {
            assert!(labels.contains(&name), "{name}: {labels:?}");
        }
        // The background and one rectangle per bar.
        assert_eq!(svg.matches("<rect").count(), 1 + 3, "{svg}");
        let bins: Vec<(f64, u64)> = (0..12).map(|i| (i as f64 * 5.0, i * 3)).collect();
        let svg = histogram("Minimum angles", "degrees", &bins, "angles").unwrap();
        assert!(svg.contains("Minimum angles") && svg.contains("degrees"));
        assert_eq!(svg.matches("<rect").count(), 1 + 12);
    }
}
