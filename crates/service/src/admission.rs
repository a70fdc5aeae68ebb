//! Turning a submitted job file into one the service is willing to run.
//!
//! A job comes from the network, so it is checked like `isostream validate` checks a file (same
//! parser, same one-line errors naming the key) and then made safe: inputs must lie under an
//! `--allow-input` root (checked on the lexical path first, so a refused path says nothing about
//! whether it exists, then on the canonical path, so symlinks cannot escape), and the output is
//! always rewritten into the job's own folder, keeping the requested format.

use std::path::{Component, Path, PathBuf};

use axum::http::StatusCode;
use isostream_pipeline::{ConfigError, JobConfig, LogConfig, RunError};

use crate::error::{ApiError, ServiceError};

/// The name errors give the submitted job (it has no file of its own).
pub(crate) const ORIGIN: &str = "job.toml";

/// The canonical `--allow-input` folders, plus their spellings as given (a root given through a
/// symlink, such as `/tmp` on some systems, is matched in both forms).
#[derive(Debug, Default)]
pub(crate) struct Roots {
    given: Vec<PathBuf>,
    canonical: Vec<PathBuf>,
}

impl Roots {
    pub fn new(dirs: &[PathBuf]) -> Result<Self, ServiceError> {
        let mut roots = Roots::default();
        for dir in dirs {
            let fail = |reason: String| ServiceError::AllowInput {
                path: dir.clone(),
                reason,
            };
            let canonical = dir
                .canonicalize()
                .map_err(|e| fail(format!("{e}; give an existing folder")))?;
            if !canonical.is_dir() {
                return Err(fail("not a folder".into()));
            }
            let given = std::path::absolute(dir).map_err(|e| fail(e.to_string()))?;
            roots.given.push(lexical(&given));
            roots.canonical.push(canonical);
        }
        Ok(roots)
    }

    /// Checks one input path of the job and returns its canonical form, which the job then uses
    /// (so a symlink swapped after the check is not followed somewhere else).
    fn admit(&self, key: &str, path: &Path) -> Result<PathBuf, ApiError> {
        if !path.is_absolute() {
            return Err(ApiError::bad_job(format!(
                "{ORIGIN}: `{key}` must be an absolute path (a submitted job has no folder to resolve it against), got {}",
                path.display()
            )));
        }
        let refused = || {
            ApiError::new(
                StatusCode::FORBIDDEN,
                format!(
                    "{ORIGIN}: `{key}` = {} is outside the folders this service may read (--allow-input)",
                    path.display()
                ),
            )
        };
        let plain = lexical(path);
        let under = |p: &Path| {
            self.given
                .iter()
                .chain(&self.canonical)
                .any(|r| p.starts_with(r))
        };
        if !under(&plain) {
            return Err(refused());
        }
        let canonical = path.canonicalize().map_err(|e| {
            ApiError::bad_job(format!("{ORIGIN}: `{key}` = {}: {e}", path.display()))
        })?;
        if !self.canonical.iter().any(|r| canonical.starts_with(r)) {
            return Err(refused());
        }
        Ok(canonical)
    }
}

impl Roots {
    /// Checks again that every input of an admitted job is the file it was admitted as: its
    /// stored path (canonical at admission) still resolves to itself, under an allowed folder.
    /// A file swapped for a symbolic link after admission was otherwise followed out of the
    /// allowed folders when the job ran.
    pub fn confirm(&self, job: &JobConfig) -> Result<(), RunError> {
        let inputs =
            job.input
                .path
                .iter()
                .map(|p| ("input.path".to_string(), p))
                .chain(job.attributes.iter().enumerate().filter_map(|(i, a)| {
                    Some((format!("attributes[{i}].path"), a.path.as_ref()?))
                }));
        for (key, path) in inputs {
            let why = match path.canonicalize() {
                Ok(now) if now != *path => format!(
                    "{} (it now resolves to {}: it was replaced since the job was submitted)",
                    path.display(),
                    now.display()
                ),
                Ok(_) if !self.canonical.iter().any(|r| path.starts_with(r)) => format!(
                    "{} (outside the --allow-input folders this service was started with)",
                    path.display()
                ),
                Ok(_) => continue,
                Err(e) => format!("{}: {e}", path.display()),
            };
            return Err(RunError::Config(ConfigError::Invalid {
                path: ORIGIN.into(),
                key,
                expected: "the file admitted at submission, under an --allow-input folder (resubmit the job)".into(),
                got: why,
            }));
        }
        Ok(())
    }
}

/// `..` and `.` removed without touching the file system.
fn lexical(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

/// A job accepted for the queue: the config to run and its TOML as stored in `job.toml`.
#[derive(Debug)]
pub(crate) struct Admitted {
    pub job: JobConfig,
    pub toml: String,
}

/// The shortest interval between two progress lines a job may ask of the service's log.
const MIN_PROGRESS_SECONDS: f64 = 1.0;

/// Parses, confines and validates a submitted job whose files will live in `job_dir`.
/// Opens the input like `isostream validate` does, so it may block on the file system.
pub(crate) fn admit(text: &str, job_dir: &Path, roots: &Roots) -> Result<Admitted, ApiError> {
    let origin = Path::new(ORIGIN);
    let mut job = JobConfig::parse(text, origin).map_err(|e| ApiError::bad_job(e.to_string()))?;
    if let Some(p) = &job.input.path {
        job.input.path = Some(roots.admit("input.path", p)?);
    }
    for (i, a) in job.attributes.iter_mut().enumerate() {
        if let Some(p) = &a.path {
            a.path = Some(roots.admit(&format!("attributes[{i}].path"), p)?);
        }
    }
    let requested = job.output.path.clone();
    job.output.path = job_dir.join(output_name(&requested));
    // Errors name the output as the client wrote it, not the folder it was moved to.
    let rewritten = job.output.path.display().to_string();
    job.validate(origin).map_err(|e| {
        ApiError::bad_job(
            e.to_string()
                .replace(&rewritten, &requested.display().to_string()),
        )
    })?;
    // What `isostream validate` checks: the input and attribute files open (and the slices
    // they hold fit), and the output format can index what the job could write.
    isostream_pipeline::preflight(&job).map_err(|e| {
        ApiError::bad_job(
            e.to_string()
                .replace(&rewritten, &requested.display().to_string()),
        )
    })?;
    // Only now, so that the job is checked as `isostream validate` checks it (its `[log]`
    // included: a bad `level` was dropped here before validation saw it, and the job admitted).
    // The service keeps every run summary and does its own logging (format, level); a job only
    // chooses how often its progress is logged, at most once a second (0: never).
    job.output.summary = true;
    job.log = LogConfig {
        progress_seconds: match job.log.progress_seconds {
            s if s > 0.0 => s.max(MIN_PROGRESS_SECONDS),
            s => s,
        },
        ..LogConfig::default()
    };
    let toml = toml::to_string(&job)
        .map_err(|e| ApiError::internal(format!("cannot store the job: {e}")))?;
    Ok(Admitted { job, toml })
}

/// `output.<ext>` with the requested extension, which picks the format. An extension that is not
/// plain letters and digits is dropped, and validation then names `output.path`.
fn output_name(requested: &Path) -> String {
    match requested.extension().and_then(|e| e.to_str()) {
        Some(ext) if !ext.is_empty() && ext.chars().all(|c| c.is_ascii_alphanumeric()) => {
            format!("output.{ext}")
        }
        _ => "output".into(),
    }
}

/// Reads a stored job back (restart): the same checks but no confinement of the inputs, which
/// was done at submission and is already in the stored paths. The output is not trusted to be
/// where the stored file says: it is always `output.<ext>` in `job_dir`, so it is derived again
/// (a service before the state folder was made absolute stored it relative to its working
/// directory, and a restart elsewhere wrote it there).
pub(crate) fn reload(text: &str, job_dir: &Path) -> Result<JobConfig, String> {
    let origin = Path::new(ORIGIN);
    let mut job = JobConfig::parse(text, origin).map_err(|e| e.to_string())?;
    job.output.path = job_dir.join(output_name(&job.output.path));
    // A service before ignored keys were refused stored every default (`retire_lag = 8` in
    // mode rate): those did nothing, and failing the job at a restart for them would lose it.
    job.simplify.drop_ignored_keys();
    job.validate(origin).map_err(|e| e.to_string())?;
    Ok(job)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPHERE: &str = "[input]\nshape = \"sphere\"\nsize = [16, 16, 16]\n[extract]\niso = 0.0\n[output]\npath = \"/etc/evil/out.ply\"\n";

    fn raw_job(path: &str) -> String {
        format!(
            "[input]\npath = \"{path}\"\ndims = [2, 2, 2]\ndtype = \"u8\"\n[extract]\niso = 0.5\n[output]\npath = \"x.smb\"\n"
        )
    }

    /// A job stored by a service before ignored keys were refused has every default written out;
    /// its reload keeps it (it was failed at the restart after an upgrade).
    #[test]
    fn a_job_stored_with_every_default_written_reloads() {
        let dir = tempfile::tempdir().unwrap();
        let stored = "[input]\nshape = \"sphere\"\nsize = [16, 16, 16]\n[extract]\niso = 0.0\n[simplify]\nmode = \"rate\"\nrate = 0.2\ninitial_rate = 0.5\nretire_lag = 8\ntime_lag = true\nisotropy = 0.0\npriority = \"geometric\"\n[output]\npath = \"output.smb\"\n";
        let job = reload(stored, dir.path()).unwrap();
        assert_eq!(job.simplify.retire_lag, None);
        assert_eq!(job.simplify.initial_rate, Some(0.5), "read in mode rate");
        // A new submission with such a key is still refused.
        let refused = admit(stored, dir.path(), &Roots::default()).unwrap_err();
        assert!(format!("{refused:?}").contains("retire_lag"), "{refused:?}");
    }

    #[test]
    fn output_is_rewritten_into_the_job_folder_keeping_the_format() {
        let dir = tempfile::tempdir().unwrap();
        let job_dir = dir.path().join("jobs/abc");
        let a = admit(SPHERE, &job_dir, &Roots::default()).unwrap();
        assert_eq!(a.job.output.path, job_dir.join("output.ply"));
        assert!(a.toml.contains("output.ply"), "{}", a.toml);
        let again = reload(&a.toml, &job_dir).unwrap();
        assert_eq!(again.output.path, a.job.output.path);
    }

    /// A job stored with its output relative to the working directory of the service that
    /// admitted it is put back into its own folder.
    #[test]
    fn a_reloaded_job_writes_into_its_folder_whatever_was_stored() {
        let job_dir = Path::new("/srv/state/jobs/abc");
        let stored = SPHERE.replace("/etc/evil/out.ply", "st/jobs/abc/output.ply");
        let job = reload(&stored, job_dir).unwrap();
        assert_eq!(job.output.path, job_dir.join("output.ply"));
    }

    /// `isostream validate`'s checks past the job file: an output that cannot index what the
    /// job could write is refused at submission, named as the client wrote it.
    #[test]
    fn an_output_past_its_index_limit_is_refused_at_submission() {
        let text = SPHERE
            .replace("[16, 16, 16]", "[2000, 2000, 2000]")
            .replace("[output]", "[simplify]\nmode = \"none\"\n[output]");
        let err = admit(&text, Path::new("/nonexistent"), &Roots::default()).unwrap_err();
        assert_eq!(err.status, StatusCode::BAD_REQUEST);
        assert!(
            err.reason.contains("could write up to") && err.reason.contains("/etc/evil/out.ply"),
            "{err:?}"
        );
    }

    #[test]
    fn a_bad_key_is_named_like_validate_does() {
        let text = SPHERE.replace("iso = 0.0", "iso = 0.0\nisovalue = 1");
        let err = admit(&text, Path::new("/nonexistent"), &Roots::default()).unwrap_err();
        assert_eq!(err.status, StatusCode::BAD_REQUEST);
        assert!(
            err.reason.contains("isovalue") && err.reason.contains(ORIGIN),
            "{err:?}"
        );
        let text = SPHERE.replace("out.ply", "out.xyz");
        let err = admit(&text, Path::new("/nonexistent"), &Roots::default()).unwrap_err();
        assert!(err.reason.contains("output.path"), "{err:?}");
        assert!(
            err.reason.contains("/etc/evil/out.xyz") && !err.reason.contains("nonexistent"),
            "the output as written: {err:?}"
        );
    }

    /// The whole job is validated as submitted, `[log]` included, although the service then
    /// logs its own way: `isostream validate` refuses this job, so the service must too.
    #[test]
    fn a_bad_log_level_is_refused_like_validate_does() {
        let text = format!("{SPHERE}[log]\nlevel = \"debugg\"\n");
        let err = admit(&text, Path::new("/nonexistent"), &Roots::default()).unwrap_err();
        assert_eq!(err.status, StatusCode::BAD_REQUEST);
        assert!(
            err.reason.starts_with("job.toml: `log.level`") && err.reason.contains("debugg"),
            "{err:?}"
        );
        let text = format!("{SPHERE}[log]\nlevel = \"debug\"\nprogress_seconds = 0.01\n");
        let a = admit(&text, Path::new("/nonexistent"), &Roots::default()).unwrap();
        assert_eq!(a.job.log.level, None, "the service's level, not the job's");
        assert_eq!(a.job.log.progress_seconds, MIN_PROGRESS_SECONDS);
    }

    #[test]
    fn inputs_outside_the_roots_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let allowed = dir.path().join("data");
        std::fs::create_dir(&allowed).unwrap();
        std::fs::write(allowed.join("v.raw"), [0u8, 1, 2, 3, 4, 5, 6, 7]).unwrap();
        std::fs::write(dir.path().join("secret.raw"), [0u8; 8]).unwrap();
        let roots = Roots::new(std::slice::from_ref(&allowed)).unwrap();
        let job_dir = dir.path().join("state/jobs/x");

        let ok = admit(
            &raw_job(&allowed.join("v.raw").to_string_lossy()),
            &job_dir,
            &roots,
        );
        assert!(ok.is_ok(), "{ok:?}");

        let escape = format!("{}/../secret.raw", allowed.display());
        let err = admit(&raw_job(&escape), &job_dir, &roots).unwrap_err();
        assert_eq!(err.status, StatusCode::FORBIDDEN, "{err:?}");
        assert!(err.reason.contains("input.path"), "{err:?}");

        let err = admit(&raw_job("/etc/passwd"), &job_dir, &roots).unwrap_err();
        assert_eq!(err.status, StatusCode::FORBIDDEN, "{err:?}");

        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(dir.path().join("secret.raw"), allowed.join("link.raw"))
                .unwrap();
            let link = allowed.join("link.raw");
            let err = admit(&raw_job(&link.to_string_lossy()), &job_dir, &roots).unwrap_err();
            assert_eq!(err.status, StatusCode::FORBIDDEN, "{err:?}");
        }

        let err = admit(&raw_job("v.raw"), &job_dir, &roots).unwrap_err();
        assert_eq!(err.status, StatusCode::BAD_REQUEST, "{err:?}");
        assert!(err.reason.contains("absolute"), "{err:?}");
    }

    #[test]
    fn no_roots_means_procedural_only() {
        let err = admit(&raw_job("/tmp/v.raw"), Path::new("/x"), &Roots::default()).unwrap_err();
        assert_eq!(err.status, StatusCode::FORBIDDEN);
    }
}
