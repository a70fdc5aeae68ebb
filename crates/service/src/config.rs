//! `isostream serve --config FILE`: the service's flags as a TOML file (see
//! `config/serve.toml`); a flag given on the command line wins over the file. Relative paths
//! are resolved against the file's folder, so the file works from any working directory.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use isostream_pipeline::LogFormat;
use serde::Deserialize;

use crate::ServiceError;

/// Every key is optional; none given means the flags' defaults.
#[derive(Debug, Default, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ServeFile {
    /// `--state`.
    pub state: Option<PathBuf>,
    /// `--listen`.
    #[serde(default, deserialize_with = "listen_address")]
    pub listen: Option<SocketAddr>,
    /// `--allow-input`, every folder.
    #[serde(default)]
    pub allow_input: Vec<PathBuf>,
    /// `--token-file` (the token itself is never written in this file, which is easier to leak).
    pub token_file: Option<PathBuf>,
    /// `--max-parallel-jobs`.
    pub max_parallel_jobs: Option<usize>,
    /// `--max-queued-jobs`.
    pub max_queued_jobs: Option<usize>,
    /// `--log-format`: `text` or `json`.
    pub log_format: Option<LogFormat>,
}

/// A `--listen` address: `IP:PORT`, or `localhost:PORT` for `127.0.0.1:PORT` (the name people
/// type; other names are not resolved, since a name may stand for several addresses).
///
/// # Errors
/// Anything else, with what to write instead.
pub fn parse_listen(text: &str) -> Result<SocketAddr, String> {
    if let Ok(addr) = text.parse() {
        return Ok(addr);
    }
    let port = text
        .rsplit_once(':')
        .filter(|(host, _)| host.eq_ignore_ascii_case("localhost"))
        .and_then(|(_, port)| port.parse::<u16>().ok());
    port.map(|p| SocketAddr::from(([127, 0, 0, 1], p)))
        .ok_or_else(|| {
            format!(
                "{text:?} is not IP:PORT (such as 127.0.0.1:8440, [::1]:8440 or localhost:8440)"
            )
        })
}

/// The token in `--token-file` (surrounding whitespace, such as a final newline, dropped).
///
/// # Errors
/// A file that cannot be read is a configuration to fix ([`ServiceError::is_bad_config`]), as
/// an empty token is: a supervisor restarting the service would only fail again.
pub fn read_token_file(path: &Path) -> Result<String, ServiceError> {
    std::fs::read_to_string(path)
        .map(|t| t.trim().to_string())
        .map_err(|e| ServiceError::TokenFile {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })
}

fn listen_address<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<SocketAddr>, D::Error> {
    let text = String::deserialize(d)?;
    parse_listen(&text)
        .map(Some)
        .map_err(serde::de::Error::custom)
}

impl ServeFile {
    pub fn load(path: &Path) -> Result<ServeFile, ServiceError> {
        let fail = |reason: String| ServiceError::Config {
            path: path.to_path_buf(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| fail(e.to_string()))?;
        let mut file: ServeFile = toml::from_str(&text).map_err(|e| {
            let line = e
                .span()
                .map_or(0, |s| text[..s.start].matches('\n').count() + 1);
            fail(format!("line {line}: {}", e.message().trim()))
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let resolve = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        file.state.iter_mut().for_each(resolve);
        file.token_file.iter_mut().for_each(resolve);
        file.allow_input.iter_mut().for_each(resolve);
        Ok(file)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_read_and_paths_resolved_against_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("serve.toml");
        std::fs::write(
            &path,
            "state = \"state\"\nlisten = \"127.0.0.1:9000\"\nallow_input = [\"/data\", \"more\"]\nmax_parallel_jobs = 2\nmax_queued_jobs = 7\nlog_format = \"json\"\n",
        )
        .unwrap();
        let f = ServeFile::load(&path).unwrap();
        assert_eq!(f.state, Some(dir.path().join("state")));
        assert_eq!(f.listen, Some("127.0.0.1:9000".parse().unwrap()));
        assert_eq!(
            parse_listen("localhost:8440"),
            Ok("127.0.0.1:8440".parse().unwrap())
        );
        assert_eq!(parse_listen("[::1]:1"), Ok("[::1]:1".parse().unwrap()));
        for bad in ["example.org:80", "localhost", "localhost:99999", "8440"] {
            assert!(parse_listen(bad).is_err(), "{bad}");
        }
        assert_eq!(
            f.allow_input,
            [PathBuf::from("/data"), dir.path().join("more")]
        );
        assert_eq!(
            (f.max_parallel_jobs, f.max_queued_jobs, f.log_format),
            (Some(2), Some(7), Some(LogFormat::Json))
        );
    }

    #[test]
    fn a_token_file_is_trimmed_and_a_missing_one_is_a_configuration_to_fix() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("token");
        std::fs::write(&path, "  s3cret\n").unwrap();
        assert_eq!(read_token_file(&path).unwrap(), "s3cret");
        let err = read_token_file(&dir.path().join("none")).unwrap_err();
        assert!(err.is_bad_config(), "{err}");
        let text = err.to_string();
        assert!(
            text.starts_with("--token-file ")
                && text.contains("none")
                && text.contains("give a readable file"),
            "{text}"
        );
    }

    #[test]
    fn an_unknown_key_is_named_with_its_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("serve.toml");
        std::fs::write(&path, "state = \"s\"\ntoken = \"x\"\n").unwrap();
        let err = ServeFile::load(&path).unwrap_err().to_string();
        assert!(
            err.contains("serve.toml") && err.contains("line 2") && err.contains("token"),
            "{err}"
        );
        let err = ServeFile::load(&dir.path().join("none.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("none.toml"), "{err}");
    }
}
