//! Checkpoints: what a run saves at a slab boundary so that `isostream run --resume` continues
//! it after a crash, a kill or Ctrl-C and writes the same bytes as a run that went through.
//!
//! **The cut.** The reader, the first stage, decides when (`[pipeline] checkpoint`) and sends a
//! marker (`flow::Msg::Cut`) on the `order` channel right behind slab `z - 1`'s reply; every
//! later stage saves its own state when the marker reaches it (`flow::Step::cut`) and passes it
//! on with the states of the stages before it (Chandy and Lamport's marker rule: the channels are
//! FIFO, so each stage saves exactly the state it has after slab `z - 1` and before slab `z`).
//! The extraction workers run ahead in any order, so they save nothing: each slab's reply
//! carries what it added to the counters and the data range, and the detector's ordered intake
//! sums them in slab order and fills them in. The detector first sends the delta it holds back,
//! the simplifier first closes its open batch (both as the next input would: a cut is never after
//! the last slab), so that the saved states are between two batches. The writer, last, flushes
//! and fsyncs its files and writes the checkpoint. The stages do not wait for each other: a
//! checkpoint costs each stage its own encoding time only.
//!
//! **What is saved.** The reader: the slice to re-read (`z`, the extractor's carried slice,
//! re-read from the input on resume and checked against its saved hash instead of stored, so a
//! checkpoint does not grow with the slice area). The extractors: their counters and the data
//! range of slabs `0..z` (a slab depends on its two slices only). The detector: its front map. The
//! prune filter (`[simplify] min_component_faces`; format 2 added it): the small pieces still
//! ahead and the open vertices it has passed on or dropped, so a resumed job skips the first
//! pass. The simplifier: its whole resident band (vertices, quadrics, attributes, candidate heap,
//! waiting queue, rank buckets, the guard's index with its ghost triangles, counters). The writer: its
//! temporary files with their lengths and its bookkeeping (`smesh::SinkState`: SMB's partial
//! block, GLB's pending normals). PLY and GLB need the final counts in a header at the top: their
//! sinks already write the body to scratch files and assemble the file at the end, so a
//! checkpoint records the scratch files' lengths too, and the header is written once, at the
//! end, from the restored counts.
//!
//! **The file.** `.NAME.ckpt` next to the output: a magic line, the checkpoint format and the
//! crate version (a checkpoint of another version is refused: the saved structures are the
//! algorithm crates' own and change between versions), the body's length, the body (bincode
//! 2.0.1 through its serde integration, fixed-width floats: every f64 comes back bit for bit),
//! and an xxHash64 of the body. A truncated or corrupt file is refused with one line; nothing is
//! decoded from a body whose hash does not match. It is written to a temporary name, fsynced,
//! renamed and the folder fsynced, after the output's files were fsynced to the saved lengths.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use serde::{Deserialize, Serialize, de::DeserializeOwned};

use crate::config::JobConfig;
use crate::error::RunError;

const MAGIC: &[u8; 16] = b"isostream-ckpt\n\0";
/// Bumped whenever the layout of the body changes (2: the prune stage's state; 3: the
/// simplifier's pass-through band and a cascade's second simplifier).
const FORMAT: u32 = 3;
const VERSION: &str = env!("CARGO_PKG_VERSION");

/// bincode's standard configuration, but with fixed-width integers: a checkpoint is dominated by
/// floats and handles, where variable-length integers save little and cost time.
fn config() -> impl bincode::config::Config {
    bincode::config::standard().with_fixed_int_encoding()
}

/// Encodes one stage's state (the stage calls it when the marker passes).
pub(crate) fn encode<T: Serialize + ?Sized>(value: &T) -> Vec<u8> {
    // Encoding into memory fails only for types serde cannot describe, which ours are not.
    bincode::serde::encode_to_vec(value, config()).unwrap_or_else(|e| {
        unreachable!("a checkpoint state always encodes: {e}");
    })
}

/// Decodes one stage's state from a checkpoint whose hash matched.
pub(crate) fn decode<T: DeserializeOwned>(path: &Path, bytes: &[u8]) -> Result<T, RunError> {
    bincode::serde::decode_from_slice(bytes, config())
        .map(|(v, _)| v)
        .map_err(|e| corrupt(path, &e.to_string()))
}

fn hash(bytes: &[u8]) -> u64 {
    twox_hash::XxHash64::oneshot(0, bytes)
}

/// Hash of a slice's values (the carried slice's check on resume).
pub(crate) fn hash_slice(values: &[f32]) -> u64 {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    hash(&bytes)
}

/// `out/x.smb` -> `out/.x.smb.ckpt`.
pub fn path_for(output: &Path) -> PathBuf {
    let name = output.file_name().unwrap_or_default().to_string_lossy();
    output.with_file_name(format!(".{name}.ckpt"))
}

/// The reader's part of the cut.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub(crate) struct ReaderState {
    /// The slice read again on resume (the extractor's lower slice): slabs `0..z` are done.
    pub z: u64,
    /// Hash of iso slice `z`, checked when it is read again.
    pub carried: u64,
    pub range: crate::range::DataRange,
}

/// The checkpoint marker as it travels through the stages, each adding its state (the reader
/// its slice and hash, the ordered intake of the extractors' slabs their counters and data
/// range, the detector, the prune filter (when `min_component_faces` is set) and the simplifier
/// their encoded states).
pub(crate) struct Cut {
    pub reader: ReaderState,
    pub extract: isostream_extract::ExtractStats,
    pub detect: Vec<u8>,
    /// Empty when the job does not prune.
    pub prune: Vec<u8>,
    pub simplify: Vec<u8>,
    /// A cascade's second simplifier (empty without one).
    pub simplify_second: Vec<u8>,
}

impl Cut {
    /// The marker the reader sends after slice `z`, whose values hash to `carried`.
    pub fn new(z: u64, carried: u64) -> Box<Cut> {
        Box::new(Cut {
            reader: ReaderState {
                z,
                carried,
                range: Default::default(),
            },
            extract: Default::default(),
            detect: Vec::new(),
            prune: Vec::new(),
            simplify: Vec::new(),
            simplify_second: Vec::new(),
        })
    }
}

/// What the stages saved at one cut, each encoded by its own stage.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Parts {
    pub reader: ReaderState,
    pub extract: isostream_extract::ExtractStats,
    pub detect: Vec<u8>,
    pub prune: Vec<u8>,
    pub simplify: Vec<u8>,
    /// A cascade's second simplifier (empty without one).
    pub simplify_second: Vec<u8>,
    pub sink: isostream_smesh::SinkState,
}

/// The whole checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Checkpoint {
    /// [`job_hash`] of the job that saved it.
    pub job: u64,
    pub input: InputIdentity,
    pub slabs_total: u64,
    pub parts: Parts,
}

impl Checkpoint {
    pub fn slabs_done(&self) -> u64 {
        self.parts.reader.z
    }

    pub fn percent(&self) -> f64 {
        100.0 * self.slabs_done() as f64 / self.slabs_total.max(1) as f64
    }
}

/// Everything of the job that decides the output bytes. Left out: how often to checkpoint, the
/// channel capacities and the extraction threads (the bytes do not depend on them:
/// `tests/checkpoint.rs`) and logging.
pub(crate) fn job_hash(job: &JobConfig) -> u64 {
    let mut job = job.clone();
    job.pipeline.checkpoint = Default::default();
    job.pipeline.channel_capacity = 0;
    job.pipeline.threads = None;
    job.log = Default::default();
    hash(&serde_json::to_vec(&job).unwrap_or_default())
}

/// What identifies the input: the source's description, its grid, the size and modification
/// time of every file the job names, and a hash of slice 0 (with the carried slice's hash, the
/// data is sampled where the run starts again).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct InputIdentity {
    pub describe: String,
    pub dims: [u64; 3],
    pub files: Vec<(PathBuf, u64, u128)>,
    pub first_slice: u64,
}

impl InputIdentity {
    pub fn of(job: &JobConfig, describe: String, dims: [u64; 3], first_slice: u64) -> Self {
        let paths = job
            .input
            .path
            .iter()
            .chain(job.attributes.iter().filter_map(|a| a.path.as_ref()));
        let files = paths
            .map(|p| {
                let meta = std::fs::metadata(p).ok();
                let mtime = meta
                    .as_ref()
                    .and_then(|m| m.modified().ok())
                    .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_nanos());
                (p.clone(), meta.map_or(0, |m| m.len()), mtime)
            })
            .collect();
        Self {
            describe,
            dims,
            files,
            first_slice,
        }
    }

    /// What differs from `now`, in words.
    fn difference(&self, now: &InputIdentity) -> Option<String> {
        if self.describe != now.describe || self.dims != now.dims {
            return Some(format!("it was {} {:?}", self.describe, self.dims));
        }
        for (a, b) in self.files.iter().zip(&now.files) {
            if a.0 != b.0 {
                return Some(format!("it read {}", a.0.display()));
            }
            if a.1 != b.1 {
                return Some(format!("{} had {} bytes", a.0.display(), a.1));
            }
            if a.2 != b.2 {
                return Some(format!("{} was modified since", a.0.display()));
            }
        }
        if self.files.len() != now.files.len() {
            return Some("it read other files".into());
        }
        (self.first_slice != now.first_slice).then(|| "slice 0 holds other values".into())
    }
}

fn corrupt(path: &Path, reason: &str) -> RunError {
    RunError::Checkpoint {
        path: path.to_path_buf(),
        reason: format!("corrupt checkpoint ({reason})"),
    }
}

/// Writes `ckpt` atomically (temporary name, fsync, rename, fsync of the folder).
pub(crate) fn write(path: &Path, ckpt: &Checkpoint) -> Result<(), RunError> {
    let fail = |reason: String| RunError::Checkpoint {
        path: path.to_path_buf(),
        reason: format!("cannot write the checkpoint: {reason}"),
    };
    let body = encode(ckpt);
    let mut head = Vec::with_capacity(64);
    head.extend_from_slice(MAGIC);
    head.extend_from_slice(&FORMAT.to_le_bytes());
    head.push(VERSION.len() as u8);
    head.extend_from_slice(VERSION.as_bytes());
    head.extend_from_slice(&(body.len() as u64).to_le_bytes());
    let dir = dir_of(path);
    // `.NAME.ckpt.XXXXXX.tmp`: recognised as stale by `stale_temp_files`.
    let prefix = format!(
        "{}.",
        path.file_name().unwrap_or_default().to_string_lossy()
    );
    let mut tmp = isostream_smesh::output_builder(&prefix)
        .tempfile_in(dir)
        .map_err(|e| fail(e.to_string()))?;
    [&head[..], &body, &hash(&body).to_le_bytes()]
        .iter()
        .try_for_each(|part| tmp.write_all(part))
        .map_err(|e| fail(e.to_string()))?;
    tmp.as_file().sync_all().map_err(|e| fail(e.to_string()))?;
    tmp.persist(path).map_err(|e| fail(e.to_string()))?;
    #[cfg(unix)]
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| fail(e.to_string()))?;
    Ok(())
}

/// Reads and checks a checkpoint: magic, format, crate version, length, hash, then decodes.
pub(crate) fn read(path: &Path) -> Result<Checkpoint, RunError> {
    let mut bytes = Vec::new();
    File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|e| RunError::Checkpoint {
            path: path.to_path_buf(),
            reason: format!("cannot read the checkpoint: {e}"),
        })?;
    let refuse = |reason: String| RunError::Checkpoint {
        path: path.to_path_buf(),
        reason,
    };
    let truncated = || refuse(format!("truncated checkpoint ({} bytes)", bytes.len()));
    let Some(rest) = bytes.strip_prefix(MAGIC) else {
        return Err(if MAGIC.starts_with(&bytes) {
            truncated()
        } else {
            refuse("not an isostream checkpoint".into())
        });
    };
    let (format, rest) = take::<4>(rest).ok_or_else(truncated)?;
    let format = u32::from_le_bytes(format);
    let ([n], rest) = take::<1>(rest).ok_or_else(truncated)?;
    let version = rest.get(..usize::from(n)).ok_or_else(truncated)?;
    let version = String::from_utf8_lossy(version).into_owned();
    if format != FORMAT || version != VERSION {
        return Err(refuse(format!(
            "written by isostream {version} (checkpoint format {format}); this isostream {VERSION} reads its own checkpoints (format {FORMAT}) only"
        )));
    }
    let rest = &rest[usize::from(n)..];
    let (len, rest) = take::<8>(rest).ok_or_else(truncated)?;
    let len = u64::from_le_bytes(len);
    let body = usize::try_from(len)
        .ok()
        .and_then(|len| rest.get(..len))
        .ok_or_else(truncated)?;
    let (sum, tail) = take::<8>(&rest[body.len()..]).ok_or_else(truncated)?;
    if !tail.is_empty() {
        return Err(corrupt(path, "bytes after the end"));
    }
    if u64::from_le_bytes(sum) != hash(body) {
        return Err(corrupt(path, "checksum mismatch"));
    }
    decode(path, body)
}

fn take<const N: usize>(bytes: &[u8]) -> Option<([u8; N], &[u8])> {
    let head = bytes.get(..N)?;
    Some((head.try_into().ok()?, &bytes[N..]))
}

/// Checks that `ckpt` belongs to this job and input.
pub(crate) fn verify(
    path: &Path,
    ckpt: &Checkpoint,
    job: &JobConfig,
    input: &InputIdentity,
) -> Result<(), RunError> {
    if ckpt.job != job_hash(job) {
        return Err(RunError::ResumeMismatch {
            path: path.to_path_buf(),
            what: "the job file changed since the checkpoint".into(),
        });
    }
    if let Some(diff) = ckpt.input.difference(input) {
        return Err(RunError::ResumeMismatch {
            path: path.to_path_buf(),
            what: format!("the input changed since the checkpoint ({diff})"),
        });
    }
    Ok(())
}

/// Removes a checkpoint and the temporary files it refers to (a run starting over, or done).
/// A checkpoint that cannot be read is removed alone.
pub(crate) fn discard(path: &Path) -> Result<(), RunError> {
    if !path.exists() {
        return Ok(());
    }
    if let Ok(ckpt) = read(path) {
        for f in ckpt.parts.sink.files() {
            let _ = std::fs::remove_file(f);
        }
    }
    std::fs::remove_file(path).map_err(|e| RunError::Checkpoint {
        path: path.to_path_buf(),
        reason: format!("cannot remove the checkpoint: {e}"),
    })
}

/// Removes the checkpoint of a completed run (its temporary files became the output or were
/// removed by the sink).
pub(crate) fn remove(path: &Path) -> Result<(), RunError> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(RunError::Checkpoint {
            path: path.to_path_buf(),
            reason: format!("cannot remove the checkpoint of the completed run: {e}"),
        }),
        _ => Ok(()),
    }
}

/// The temporary files a readable checkpoint of `output` refers to (not stale: a resume needs
/// them).
pub(crate) fn referenced_files(output: &Path) -> Vec<PathBuf> {
    read(&path_for(output))
        .map(|c| c.parts.sink.files().map(Path::to_path_buf).collect())
        .unwrap_or_default()
}

/// What a resume of `output` needs: its checkpoint and the files it refers to; empty when there
/// is no readable checkpoint.
pub fn resumable_files(output: &Path) -> Vec<PathBuf> {
    let files = referenced_files(output);
    match files.is_empty() {
        true => files,
        false => std::iter::once(path_for(output)).chain(files).collect(),
    }
}

fn dir_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Checkpoint {
        Checkpoint {
            job: 7,
            input: InputIdentity {
                describe: "procedural sphere".into(),
                dims: [4, 5, 6],
                files: vec![],
                first_slice: 9,
            },
            slabs_total: 5,
            parts: Parts {
                reader: ReaderState {
                    z: 3,
                    carried: 11,
                    range: Default::default(),
                },
                extract: Default::default(),
                detect: vec![1, 2, 3],
                prune: vec![5, 6],
                simplify: vec![4; 100],
                simplify_second: vec![5; 10],
                sink: sink_state(),
            },
        }
    }

    /// A real sink's state (its fields are smesh's own).
    fn sink_state() -> isostream_smesh::SinkState {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = isostream_smesh::create_sink(
            &dir.path().join("m.smb"),
            &Default::default(),
            &Default::default(),
        )
        .unwrap();
        sink.checkpoint().unwrap()
    }

    #[test]
    fn a_checkpoint_round_trips_and_every_damage_is_one_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".m.smb.ckpt");
        write(&path, &sample()).unwrap();
        let back = read(&path).unwrap();
        assert_eq!(back.percent(), 60.0);
        assert_eq!(back.parts.simplify, vec![4; 100]);
        let good = std::fs::read(&path).unwrap();
        let damaged = |bytes: &[u8]| {
            std::fs::write(&path, bytes).unwrap();
            let e = read(&path).unwrap_err().to_string();
            assert!(!e.contains('\n'), "{e}");
            assert!(e.contains(".m.smb.ckpt"), "{e}");
            e
        };
        for cut in [0, 5, 16, 20, 30, good.len() / 2, good.len() - 1] {
            let e = damaged(&good[..cut]);
            assert!(e.contains("truncated"), "cut at {cut}: {e}");
        }
        let mut flipped = good.clone();
        let mid = good.len() / 2;
        flipped[mid] ^= 0x40;
        assert!(damaged(&flipped).contains("checksum"));
        let mut old = good.clone();
        old[16] = 0;
        assert!(damaged(&old).contains("format 0"));
        assert!(damaged(b"PK\x03\x04 something else entirely").contains("not an isostream"));
    }
}
