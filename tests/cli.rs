//! The `isostream` binary as a user meets it: the README's commands, and a clear one-line error
//! with a non-zero exit for every kind of bad input, leaving no half-written output behind.

mod common;

use std::path::Path;
use std::process::Command;

use common::{Mesh, TestVolume, assert_one_line_error, isostream, random_blobs, stderr};

fn write_job(dir: &Path, body: &str) -> String {
    let job = dir.join("job.toml");
    std::fs::write(&job, body).unwrap();
    job.to_string_lossy().into_owned()
}

fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "job.toml" && n != "volume.raw")
        .collect()
}

#[test]
fn example_job_runs_and_converts() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"torus\"\nsize = [40, 40, 40]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.25\n[output]\npath = \"out/torus.smb\"\n",
    );
    let o = isostream(&["validate", &job]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = isostream(&["run", &job]);
    assert!(o.status.success(), "{}", stderr(&o));
    let smb = dir.path().join("out/torus.smb");
    assert!(dir.path().join("out/torus.smb.run.json").exists());
    let o = isostream(&["check", &smb.to_string_lossy()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for ext in ["ply", "obj", "sma"] {
        let target = dir.path().join(format!("out/torus.{ext}"));
        let o = isostream(&["convert", &smb.to_string_lossy(), &target.to_string_lossy()]);
        assert!(o.status.success(), "{}", stderr(&o));
        let r = Mesh::read(&target).check();
        assert!(r.is_closed_manifold(), "{ext}: {r:?}");
        assert_eq!(r.euler(), 0, "{ext}: a torus has Euler characteristic 0");
    }
}

/// `validate` and the logs name the mode as the job file does ("mode Rate" and `mode=Rate` were
/// its `Debug` name), and `validate` says the faces target of `[output] faces`.
#[test]
fn validate_and_the_logs_say_the_mode_as_the_job_file_does() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"torus\"\nsize = [24, 24, 24]\n[extract]\niso = 0.0\n[output]\npath = \"t.smb\"\nfaces = 500\n",
    );
    let o = isostream(&["validate", &job]);
    assert!(o.status.success(), "{}", stderr(&o));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.contains(", mode rate to 500 faces, output "), "{said}");
    let o = Command::new(env!("CARGO_BIN_EXE_isostream"))
        .args(["run", &job])
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let start = stderr(&o)
        .lines()
        .find(|l| l.contains("job start"))
        .map(str::to_string)
        .unwrap_or_default();
    assert!(start.contains("mode=rate"), "{}", stderr(&o));
}

/// `convert --ascii` writes ASCII PLY and `convert --normals` GLB normals (the formats had
/// both, but no flag reached them); either flag on an output without that choice is refused.
#[test]
fn convert_writes_ascii_ply_and_glb_normals_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"torus\"\nsize = [24, 24, 24]\n[extract]\niso = 0.0\n[output]\npath = \"t.smb\"\n",
    );
    assert!(isostream(&["run", &job]).status.success());
    let smb = dir.path().join("t.smb").to_string_lossy().into_owned();
    let path = |name: &str| dir.path().join(name).to_string_lossy().into_owned();
    let faces = Mesh::read(&dir.path().join("t.smb")).triangles.len();

    let o = isostream(&["convert", "--ascii", &smb, &path("a.ply")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(dir.path().join("a.ply")).unwrap();
    assert!(
        text.starts_with("ply\nformat ascii 1.0\n"),
        "{}",
        &text[..40]
    );
    assert_eq!(Mesh::read(&dir.path().join("a.ply")).triangles.len(), faces);

    for (flag, glb) in [("--normals", "n.glb"), ("--json", "plain.glb")] {
        let o = isostream(&["convert", flag, &smb, &path(glb)]);
        assert!(o.status.success(), "{}", stderr(&o));
        let bytes = std::fs::read(dir.path().join(glb)).unwrap();
        let has_normals = bytes.windows(8).any(|w| w == b"\"NORMAL\"");
        assert_eq!(has_normals, flag == "--normals", "{glb}");
    }

    for (flag, out) in [("--ascii", "o.obj"), ("--normals", "o.ply")] {
        let o = isostream(&["convert", flag, &smb, &path(out)]);
        assert_one_line_error(&o, 2, &[flag, out, "drop", "output only, not"]);
        assert!(!dir.path().join(out).exists());
    }
}

/// An input path holding an `é` and a line break runs (exit 0; the line break in the header
/// comment naming the input failed it with exit 1, after `validate` had passed it), and the PLY
/// it writes has a pure ASCII header: the comment names the path with those escaped.
#[test]
fn an_input_path_outside_printable_ascii_runs_and_writes_an_ascii_header() {
    let dir = tempfile::tempdir().unwrap();
    let odd = dir.path().join("dir \u{e9}\nx");
    std::fs::create_dir(&odd).unwrap();
    let job = random_blobs([12, 12, 12], 2, 7).job(&odd, "rate = 0.5", "out.ply");
    let job = job.to_string_lossy();
    let o = isostream(&["validate", &job]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = isostream(&["run", "--quiet", &job]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let ply = std::fs::read(odd.join("out.ply")).unwrap();
    let end = ply
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("a PLY header");
    let header = &ply[..end];
    assert!(header.is_ascii(), "{}", String::from_utf8_lossy(header));
    let header = String::from_utf8_lossy(header);
    assert!(
        header.contains("\ncomment input ")
            && header.contains("/dir \\u{e9}\\u{a}x/volume.raw iso 0.5\n"),
        "{header}"
    );
}

#[test]
fn bundled_example_configs_validate() {
    for entry in std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples")).unwrap()
    {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        if text.contains("shared/data")
            && !Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data")).exists()
        {
            continue; // real-data examples need ../shared beside the checkout
        }
        let o = isostream(&["validate", &path.to_string_lossy()]);
        assert!(o.status.success(), "{}: {}", path.display(), stderr(&o));
    }
}

#[test]
fn unknown_key_names_key_and_file() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0.0\nisovalue = 1\n[output]\npath = \"o.smb\"\n",
    );
    assert_one_line_error(&isostream(&["run", &job]), 2, &["isovalue", "job.toml"]);
}

#[test]
fn impossible_rate_names_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0.0\n[simplify]\nrate = 0\n[output]\npath = \"o.smb\"\n",
    );
    assert_one_line_error(
        &isostream(&["validate", &job]),
        2,
        &["simplify.rate", "(0, 1]"],
    );
}

/// A job whose output format cannot index (SMB) or count (binary STL's u32 triangle count) what
/// it could write is refused by `validate` as by `run`, before any work (a procedural 2000^3
/// sphere kept whole is not generated).
#[test]
fn validate_refuses_an_output_past_its_index_limit() {
    for (output, fix) in [("o.smb", ".sma"), ("o.stl", ".obj")] {
        let dir = tempfile::tempdir().unwrap();
        let job = write_job(
            dir.path(),
            &format!(
                "[input]\nshape = \"sphere\"\nsize = [2000, 2000, 2000]\n[extract]\niso = 0.0\n[simplify]\nmode = \"none\"\n[output]\npath = \"{output}\"\n"
            ),
        );
        for command in ["validate", "run"] {
            assert_one_line_error(
                &isostream(&[command, &job]),
                2,
                &["output.path", output, "could write up to", fix],
            );
        }
        assert!(!dir.path().join(output).exists());
    }
}

#[test]
fn wrong_dims_name_the_file_and_both_sizes() {
    let dir = tempfile::tempdir().unwrap();
    let vol = TestVolume {
        dims: [4, 4, 4],
        data: vec![0.0; 64],
        iso: 0.5,
    };
    let job = vol.job(dir.path(), "mode = \"none\"", "o.smb");
    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("[4, 4, 4]", "[4, 4, 5]");
    std::fs::write(&job, text).unwrap();
    let o = isostream(&["run", &job.to_string_lossy()]);
    assert_one_line_error(&o, 2, &["volume.raw", "256", "320"]);
    assert!(
        leftovers(dir.path()).is_empty(),
        "{:?}",
        leftovers(dir.path())
    );
}

#[test]
fn missing_input_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\npath = \"nothing.raw\"\ndims = [4, 4, 4]\ndtype = \"u8\"\n[extract]\niso = 1\n[output]\npath = \"o.smb\"\n",
    );
    assert_one_line_error(&isostream(&["run", &job]), 2, &["nothing.raw"]);
}

#[test]
fn unwritable_output_fails_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\n[extract]\niso = 0.0\n[output]\npath = \"/proc/isostream/o.smb\"\n",
    );
    assert_one_line_error(&isostream(&["run", &job]), 2, &["output.path", "/proc"]);
}

/// NaN voxels are outside the surface, counted in the run summary and warned about.
#[test]
fn nan_voxels_are_outside_counted_and_warned() {
    let dir = tempfile::tempdir().unwrap();
    let mut vol = random_blobs([16, 16, 16], 1, 7);
    for v in vol.data.iter_mut().step_by(97) {
        *v = f32::NAN;
    }
    let job = vol.job(dir.path(), "mode = \"none\"", "o.smb");
    let o = isostream(&["run", &job.to_string_lossy()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("o.smb.run.json")).unwrap())
            .unwrap();
    let nan = summary["extract"]["non_finite_voxels"].as_u64().unwrap();
    assert!(nan > 0, "{summary}");
    // Said, not only counted: a mostly non-finite volume made a mesh of something else
    // silently.
    let said = format!("{nan} of the 4096 voxels");
    assert!(
        summary["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains(&said)),
        "{summary}"
    );
    let log = stderr(&o);
    assert!(
        log.lines()
            .any(|l| l.contains("WARN") && l.contains(&said) && l.contains("treated as outside")),
        "{log}"
    );
    let r = Mesh::read(&dir.path().join("o.smb")).check();
    assert!(r.is_valid_manifold(), "{r:?}");
}

/// Finite f64 values beyond f32's range (a core of 1e40) were made infinite: meshed as
/// outside (a spurious inner surface) and warned about as "NaN or infinite", which the file
/// does not hold. They read as ±f32::MAX, are counted and warned about naming the file, through
/// every wrapper of a source (a flipped NRRD, an upsampled input, an attribute volume), and the
/// mesh is that of the same data with the core at any large f32 value.
#[test]
fn f64_beyond_f32_is_saturated_counted_and_warned() {
    let dir = tempfile::tempdir().unwrap();
    let n = 14u64;
    let field = |core: f64| -> Vec<f64> {
        (0..n * n * n)
            .map(|i| {
                let p = [i % n, i / n % n, i / (n * n)].map(|c| c as f64 - 6.5);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                if r < 2.5 { core } else { 6.0 - r }
            })
            .collect()
    };
    let values = field(1e40);
    let core = values.iter().filter(|&&v| v == 1e40).count() as u64;
    let le: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.path().join("core.raw"), &le).unwrap();
    let twin: Vec<u8> = field(1e6).iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.path().join("twin.raw"), &twin).unwrap();
    let mut nrrd = format!(
        "NRRD0004\ntype: double\ndimension: 3\nsizes: {n} {n} {n}\nendian: big\nencoding: raw\n\
         space: left-posterior-superior\nspace directions: (-1,0,0) (0,-1,0) (0,0,1)\nspace origin: (0,0,0)\n\n"
    )
    .into_bytes();
    nrrd.extend(values.iter().flat_map(|v| v.to_be_bytes()));
    std::fs::write(dir.path().join("core.nrrd"), nrrd).unwrap();
    let raw = |name: &str| format!("path = \"{name}\"\ndims = [{n}, {n}, {n}]\ndtype = \"f64\"\n");
    let run = |name: &str, input: &str, extra: &str| {
        let job = dir.path().join(format!("{name}.toml"));
        std::fs::write(
            &job,
            format!(
                "[input]\n{input}[extract]\niso = 0.5\n[simplify]\nmode = \"none\"\n[output]\npath = \"{name}.smb\"\n{extra}"
            ),
        )
        .unwrap();
        let o = isostream(&["run", &job.to_string_lossy()]);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(format!("{name}.smb.run.json"))).unwrap(),
        )
        .unwrap();
        let mesh = Mesh::read(&dir.path().join(format!("{name}.smb")));
        (summary, stderr(&o), mesh)
    };
    let said = |summary: &serde_json::Value, log: &str, needle: &str| {
        let warnings = summary["warnings"].as_array().unwrap();
        assert!(
            warnings
                .iter()
                .any(|w| w.as_str().unwrap().contains(needle)),
            "{needle}: {summary}"
        );
        assert!(
            !warnings
                .iter()
                .any(|w| w.as_str().unwrap().contains("NaN or infinite")),
            "{summary}"
        );
        assert!(
            log.lines()
                .any(|l| l.contains("WARN") && l.contains(needle)),
            "{log}"
        );
    };
    let (_, _, want) = run("twin", &raw("twin.raw"), "");
    let attribute = format!("[[attributes]]\nname = \"a\"\n{}", raw("core.raw"));
    for (name, input, extra) in [
        ("raw", raw("core.raw"), String::new()),
        ("nrrd", "path = \"core.nrrd\"\n".to_string(), String::new()),
        (
            "upsampled",
            raw("core.raw") + "upsample = [2, 2, 2]\n",
            String::new(),
        ),
        ("attribute", raw("core.raw"), attribute),
    ] {
        let (summary, log, mesh) = run(name, &input, &extra);
        let extract = &summary["extract"];
        assert_eq!(extract["non_finite_voxels"], 0, "{name}: {summary}");
        assert_eq!(extract["saturated_voxels"], core, "{name}: {summary}");
        let file = match name {
            "nrrd" => "core.nrrd",
            // Counted in the source's voxels.
            "upsampled" => "core.raw upsampled 2x2x2",
            _ => "core.raw",
        };
        said(
            &summary,
            &log,
            &format!("{file}: {core} voxels hold finite values beyond f32's range"),
        );
        // One closed surface: no inner one around the core.
        let report = mesh.check();
        assert!(report.is_valid_manifold(), "{name}: {report:?}");
        assert_eq!(report.components.len(), 1, "{name}: {report:?}");
        assert_eq!(report.boundary_edges, 0, "{name}: {report:?}");
        match name {
            "raw" => {
                assert_eq!(mesh.positions, want.positions);
                assert_eq!(mesh.triangles, want.triangles);
            }
            "attribute" => {
                assert_eq!(
                    extract["saturated_attribute_voxels"], core,
                    "{name}: {summary}"
                );
                said(
                    &summary,
                    &log,
                    &format!("{core} voxels of the attribute volumes (`a` ("),
                );
            }
            _ => {}
        }
    }
}

/// An LPS NRRD (x and y step backwards from the origin): the dropped flips are one warning in
/// the run summary, and a warning line of `validate`.
/// An LPS NRRD (x and y stepping backwards from the origin) is meshed where its header puts
/// it: the same surface as the same voxels stored aligned (reversed along x and y, from the
/// box's low corner), oriented the same way, no warning; `measure --volume` finds the output
/// on its full surface.
#[test]
fn axis_flips_are_applied() {
    let dir = tempfile::tempdir().unwrap();
    let n = 12;
    let vol = random_blobs([n, n, n], 1, 3);
    let write = |name: &str, directions: &str, origin: &str, data: &[f32]| {
        let mut nrrd = format!(
            "NRRD0004\ntype: float\ndimension: 3\nsizes: {n} {n} {n}\nendian: little\nencoding: raw\n\
             space: left-posterior-superior\nspace directions: {directions}\nspace origin: {origin}\n\n"
        )
        .into_bytes();
        nrrd.extend(data.iter().flat_map(|v| v.to_le_bytes()));
        std::fs::write(dir.path().join(name), nrrd).unwrap();
        let job = dir.path().join(format!("{name}.toml"));
        std::fs::write(
            &job,
            format!(
                "[input]\npath = \"{name}\"\n[extract]\niso = {}\n[simplify]\nmode = \"none\"\n[output]\npath = \"{name}.smb\"\n",
                vol.iso
            ),
        )
        .unwrap();
        job.to_string_lossy().into_owned()
    };
    let flipped = write(
        "lps.nrrd",
        "(-0.5,0,0) (0,-0.8,0) (0,0,1.2)",
        "(10,-5,3)",
        &vol.data,
    );
    let n = n as usize;
    let reversed: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, i / n % n, i / (n * n));
            vol.data[(n - 1 - x) + n * ((n - 1 - y) + n * z)]
        })
        .collect();
    let aligned = write(
        "aligned.nrrd",
        "(0.5,0,0) (0,0.8,0) (0,0,1.2)",
        "(4.5,-13.8,3)",
        &reversed,
    );
    // x alone flipped (an odd number of flips: the winding is swapped back too).
    let y_reversed: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (i % n, i / n % n, i / (n * n));
            vol.data[x + n * ((n - 1 - y) + n * z)]
        })
        .collect();
    let las = write(
        "las.nrrd",
        "(-0.5,0,0) (0,0.8,0) (0,0,1.2)",
        "(10,-13.8,3)",
        &y_reversed,
    );
    let o = isostream(&["validate", &flipped]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!String::from_utf8_lossy(&o.stdout).contains("warning"));
    let mut meshes = Vec::new();
    for (job, mesh) in [
        (&flipped, "lps.nrrd.smb"),
        (&aligned, "aligned.nrrd.smb"),
        (&las, "las.nrrd.smb"),
    ] {
        let o = isostream(&["run", job]);
        assert!(o.status.success(), "{}", stderr(&o));
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join(format!("{mesh}.run.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(
            summary["warnings"].as_array().unwrap().len(),
            0,
            "{summary}"
        );
        meshes.push(Mesh::read(&dir.path().join(mesh)));
    }
    let bbox = |m: &Mesh| {
        (0..3)
            .map(|k| {
                let c = m.positions.iter().map(|p| p[k]);
                (
                    c.clone().fold(f64::INFINITY, f64::min),
                    c.fold(f64::NEG_INFINITY, f64::max),
                )
            })
            .collect::<Vec<_>>()
    };
    let b = bbox(&meshes[1]);
    for a in [bbox(&meshes[0]), bbox(&meshes[2])] {
        for k in 0..3 {
            assert!(
                (a[k].0 - b[k].0).abs() < 1e-4 && (a[k].1 - b[k].1).abs() < 1e-4,
                "{a:?} {b:?}"
            );
        }
        assert!(a[0].0 >= 4.5 - 1e-6 && a[0].1 <= 10.0 + 1e-6, "{a:?}");
    }
    // Signed volume: the same sign (orientation) and about the same size.
    let vb = meshes[1].signed_volume();
    for va in [meshes[0].signed_volume(), meshes[2].signed_volume()] {
        assert!(
            va * vb > 0.0 && (va - vb).abs() < 0.02 * vb.abs(),
            "{va} {vb}"
        );
    }
    // An attribute stored with other flips than the iso volume's would pair mirrored voxels.
    let with_attribute = dir.path().join("attr.toml");
    std::fs::write(
        &with_attribute,
        std::fs::read_to_string(&flipped).unwrap()
            + "[[attributes]]\nname = \"a\"\npath = \"aligned.nrrd\"\n",
    )
    .unwrap();
    assert_one_line_error(
        &isostream(&["validate", &with_attribute.to_string_lossy()]),
        2,
        &["aligned.nrrd", "same axis directions"],
    );
    let out = dir
        .path()
        .join("lps.nrrd.smb")
        .to_string_lossy()
        .into_owned();
    let o = isostream(&["measure", "--volume", &flipped, &out, "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(m["distances"]["hausdorff"].as_f64().unwrap() < 1e-3, "{m}");
}

#[test]
fn ctrl_c_stops_with_130_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"gyroid\"\nsize = [400, 400, 400]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.1\n[output]\npath = \"big.smb\"\n",
    );
    let child = Command::new(env!("CARGO_BIN_EXE_isostream"))
        .args(["run", &job])
        .env("RUST_LOG", "warn")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(700));
    let killed = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let o = child.wait_with_output().unwrap();
    assert_one_line_error(&o, 130, &["interrupted"]);
    assert!(
        leftovers(dir.path()).is_empty(),
        "{:?}",
        leftovers(dir.path())
    );
}

/// A bad command line is one line too (clap's layout spread it over five, a blank line and a
/// "For more information" among them), naming what is wrong, exit 2; `--help` keeps its text.
#[test]
fn command_line_errors_are_one_line() {
    for (args, needles) in [
        (&["run"][..], &["<JOB>", "usage: isostream run"][..]),
        (&["frobnicate"], &["unrecognized subcommand 'frobnicate'"]),
        // A close typo names the subcommand meant, short names too (clap alone said nothing
        // for these two).
        (
            &["rnu", "x.toml"],
            &["unrecognized subcommand 'rnu'; did you mean `run`?; usage:"],
        ),
        (&["rn", "x.toml"], &["did you mean `run`?"]),
        (&["valdate", "x.toml"], &["did you mean `validate`?"]),
        (
            &["serve", "--listen", "example.org:1"],
            &["--listen", "is not IP:PORT"],
        ),
        (&["run", "--bogus", "x.toml"], &["'--bogus'"]),
    ] {
        let o = isostream(args);
        assert_one_line_error(&o, 2, needles);
        let lines = stderr(&o).lines().filter(|l| !l.trim().is_empty()).count();
        assert_eq!(lines, 1, "{}", stderr(&o));
    }
    let o = isostream(&["run", "--help"]);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).lines().count() > 3);
}

/// Trial bug: `measure` and `convert` took an OBJ whose faces are in `g` (or `o`) groups for
/// one piece per group (8 vertices, 2 components, not closed for a tetrahedron in two groups),
/// and never counted the vertices no face uses.
#[test]
fn obj_groups_keep_the_file_s_vertex_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("tet_g.obj");
    std::fs::write(
        &obj,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 7 7 7\ng a\nf 1 3 2\nf 1 2 4\ng b\nf 1 4 3\nf 2 3 4\n",
    )
    .unwrap();
    let obj = obj.to_string_lossy().into_owned();
    let o = isostream(&["measure", "--json", &obj]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let q = &report["quality"];
    assert_eq!(q["vertices"], 4, "{report}");
    assert_eq!(
        (&q["components"], &q["closed"]),
        (&1.into(), &true.into()),
        "{report}"
    );
    let smb = dir.path().join("tet.smb").to_string_lossy().into_owned();
    let o = isostream(&["convert", "--json", &obj, &smb]);
    assert!(o.status.success(), "{}", stderr(&o));
    let stats: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(stats["vertices"], 4, "{stats}");
    assert_eq!(stats["dropped_vertices"], 1, "{stats}");
}

/// Trial bug: `check --json` on an invalid file printed nothing on stdout.
#[test]
fn check_json_answers_for_an_invalid_file_too() {
    let dir = tempfile::tempdir().unwrap();
    let sma = dir.path().join("bad.sma");
    std::fs::write(&sma, "v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap();
    let o = isostream(&["check", "--json", &sma.to_string_lossy()]);
    assert_one_line_error(&o, 2, &["bad.sma", "references vertex 2"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["valid"], false, "{v}");
    let error = v["error"].as_str().unwrap();
    assert!(stderr(&o).contains(error), "{error}");
}

/// Trial bug: a PLY double attribute beyond f32 became inf in `convert`'s output, which
/// `check` then called valid.
#[test]
fn ply_attribute_beyond_f32_is_refused_by_convert() {
    let dir = tempfile::tempdir().unwrap();
    let ply = dir.path().join("big.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
         property float z\nproperty double t\nelement face 1\n\
         property list uchar int vertex_indices\nend_header\n0 0 0 1\n1 0 0 1e300\n0 1 0 2\n3 0 1 2\n",
    )
    .unwrap();
    let out = dir.path().join("big.smb");
    let o = isostream(&["convert", &ply.to_string_lossy(), &out.to_string_lossy()]);
    assert_one_line_error(&o, 2, &["big.ply", "vertex 1", "attribute `t`", "1e300"]);
    assert!(!out.exists());
}

/// Trial bug: `measure --help` listed four of the six formats it reads.
#[test]
fn measure_help_names_every_format() {
    let o = isostream(&["measure", "--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    assert!(help.contains(".stl, .glb"), "{help}");
}

/// Trial bug: `measure --volume` counted the output samples with no full-resolution point within
/// its search radius (4 voxel diagonals) at the radius, so the Hausdorff distance and the
/// "99.9 % within" were the radius, silently (19.07 on headsq at R = 0.01 where the exact
/// distance is 24.85). A run's sphere plus a small tetrahedron near the box's corner, 9.6 to
/// 10.2 voxels from the sphere (radius 8.05 around the centre 11.5): the output -> full
/// direction and the undirected distances are the tetrahedron's, measured in a second pass.
#[test]
fn measure_finds_the_exact_distance_of_a_piece_farther_than_the_search_radius() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"sphere\"\nsize = [24, 24, 24]\n[extract]\niso = 0.0\n\
         [simplify]\nrate = 0.2\n[output]\npath = \"out.smb\"\n",
    );
    let o = isostream(&["run", "--quiet", &job]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mesh = Mesh::read(&dir.path().join("out.smb"));
    let mut obj = String::new();
    let corner = [
        [1.0, 1.0, 1.0],
        [2.0, 1.0, 1.0],
        [1.0, 2.0, 1.0],
        [1.0, 1.0, 2.0],
    ];
    for p in mesh.positions.iter().chain(&corner) {
        obj += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    let n = mesh.positions.len() as u32 + 1;
    let tetra = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]].map(|t| t.map(|i| n + i));
    for t in mesh.triangles.iter().map(|t| t.map(|i| i + 1)).chain(tetra) {
        obj += &format!("f {} {} {}\n", t[0], t[1], t[2]);
    }
    let far = dir.path().join("far.obj");
    std::fs::write(&far, obj).unwrap();
    let far = far.to_string_lossy().into_owned();

    let o = isostream(&["measure", "--volume", &job, &far, "--json"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let d = &report["distances"];
    let radius = d["max_distance"].as_f64().unwrap();
    assert!((radius - 4.0 * 3f64.sqrt()).abs() < 1e-9, "{d}");
    let o2f = &d["output_to_full"];
    let hausdorff = o2f["hausdorff"].as_f64().unwrap();
    // The tetrahedron's samples: farther than the radius, nearer than its farthest corner.
    assert!((9.0..10.3).contains(&hausdorff), "{d}");
    assert_eq!(d["hausdorff"].as_f64(), Some(hausdorff), "{d}");
    // Its share of the samples (about 0.2 %) puts the 99.9th percentile on it too.
    let p999 = d["p999"].as_f64().unwrap();
    assert!(p999 > radius && p999 <= hausdorff, "{d}");
    let far_samples = d["far_samples"].as_u64().unwrap();
    assert!(far_samples > 0 && far_samples < 100, "{d}");

    let o = isostream(&["measure", "--volume", &job, &far]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains(&format!(
            "{far_samples} output samples had no full-resolution point within 6.928203: measured exactly in a second pass"
        )),
        "{text}"
    );
    assert!(!text.contains("lower bound"), "{text}");
}

/// A failed write of a command's answer to stdout panicked (exit 101 and a backtrace): on a
/// full disk (`> /dev/full`) it is one error line and exit 1, after the work (the run's mesh is
/// written); a reader that closed the pipe (`| head -c 10`) ends the command quietly, exit 0.
#[cfg(target_os = "linux")]
#[test]
fn a_failed_write_to_stdout_is_an_error_not_a_panic() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"sphere\"\nsize = [12, 12, 12]\n[extract]\niso = 0.0\n[output]\npath = \"o.smb\"\n",
    );
    let mesh = dir.path().join("o.smb").to_string_lossy().into_owned();
    let ply = dir.path().join("o.ply").to_string_lossy().into_owned();
    let bin = || {
        let mut c = Command::new(env!("CARGO_BIN_EXE_isostream"));
        c.env("RUST_LOG", "warn").stderr(Stdio::piped());
        c
    };
    let full = || Stdio::from(std::fs::File::create("/dev/full").unwrap());
    let o = bin()
        .args(["run", "--quiet", &job])
        .stdout(full())
        .output()
        .unwrap();
    assert_one_line_error(
        &o,
        1,
        &[
            "o.smb: written, but not its summary line: cannot write to standard output: No space left on device",
        ],
    );
    assert!(Mesh::read(Path::new(&mesh)).check().is_valid_manifold());
    let commands: [&[&str]; 5] = [
        &["validate", &job],
        &["check", &mesh, "--json"],
        &["measure", &mesh, "--json"],
        &["measure", &mesh],
        &["convert", &mesh, &ply, "--json"],
    ];
    for args in commands {
        let o = bin().args(args).stdout(full()).output().unwrap();
        assert_one_line_error(&o, 1, &["cannot write to standard output: No space left"]);
        // The reader gone before the answer comes.
        let mut child = bin().args(args).stdout(Stdio::piped()).spawn().unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}: {}", stderr(&o));
        assert_eq!(stderr(&o), "", "{args:?}");
    }
}

/// Under an address-space cap (`ulimit -v`, as HPC schedulers set) a small job runs: glibc made
/// an arena of 64 MiB of address space for each thread that allocates, so a job resident in 48
/// MiB reserved over 600 MB and a 400 MB cap aborted it in the allocator (exit 134, its
/// temporary files left). The arenas are capped at the core count (`main.rs`).
#[test]
fn a_job_runs_under_an_address_space_cap() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"gyroid\"\nsize = [96, 96, 96]\n[extract]\niso = 0.0\n[simplify]\nrate = 0.2\n[output]\npath = \"capped.smb\"\n",
    );
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get()) as u64;
    let cap_kib = (160 + 64 * cores) * 1024;
    let o = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v {cap_kib} && exec \"$0\" run --quiet \"$1\"",
        ))
        .arg(env!("CARGO_BIN_EXE_isostream"))
        .arg(&job)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(o.status.success(), "cap {cap_kib} KiB: {}", stderr(&o));
    assert!(dir.path().join("capped.smb").is_file());
}

/// With stderr a pipe whose reader is gone (`isostream run JOB 2>&1 | head -1`), a run still
/// makes its mesh and exits 0, and a failing command still exits with its code: the first log
/// line nobody could read made tracing-subscriber report it with `eprintln!`, which panicked
/// (exit 101; with progress lines every second the run was aborted and its output lost).
#[cfg(unix)]
#[test]
fn a_closed_stderr_changes_no_exit_code_and_loses_no_mesh() {
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    let job = write_job(
        dir.path(),
        "[input]\nshape = \"gyroid\"\nsize = [64, 64, 64]\n[extract]\niso = 0.0\n[output]\npath = \"o.smb\"\n[log]\nprogress_seconds = 1\n",
    );
    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[input]\nshape = \"sphere\"\nsize = [8, 8, 8]\nbogus = 1\n",
    )
    .unwrap();
    let bad = bad.to_string_lossy().into_owned();
    let exit = |args: &[&str]| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_isostream"))
            .args(args)
            .env("RUST_LOG", "debug")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stderr.take());
        child.wait().unwrap().code()
    };
    assert_eq!(exit(&["run", &job]), Some(0));
    let mesh = dir.path().join("o.smb");
    assert!(Mesh::read(&mesh).check().is_valid_manifold());
    assert_eq!(exit(&["validate", &bad]), Some(2));
    assert_eq!(exit(&["run", &bad]), Some(2));
    assert_eq!(exit(&["check", &job]), Some(2));
    assert_eq!(exit(&["bogus-command"]), Some(2));
}
