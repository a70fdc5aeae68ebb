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
//! block, GLB's pending normals). The first pass's counts (`[output] faces`,
//! `min_component_faces`, a stage count decided by the largest slab; format 39 added them): the
//! faces the simplifier receives and the largest slab's, which set the rate and the stage count,
//! so a resumed job does not run that pass over the whole volume again. PLY and GLB need the final counts in a header at the top: their
//! sinks already write the body to scratch files and assemble the file at the end, so a
//! checkpoint records the scratch files' lengths too, and the header is written once, at the
//! end, from the restored counts.
//!
//! **The file.** `.NAME.ckpt` next to the output: a magic line, the checkpoint format and the
//! crate version (a checkpoint of another version is refused: the saved structures are the
//! algorithm crates' own and change between versions), the lengths of its three sections, the
//! simplifier's section, a cascade's second simplifier's (empty without one), the rest (every
//! other part, [`Checkpoint`]), and an xxHash64 of all three. All are bincode 2.0.1 through its
//! serde integration, fixed-width floats: every f64 comes back bit for bit. A truncated or
//! corrupt file is refused with one line; nothing is decoded from a file whose hash does not
//! match.
//!
//! **Memory.** The simplifier's state is the band itself (tens of MiB): it is encoded straight
//! into the checkpoint's temporary file ([`Partial`], buffered and hashed on the way) by the
//! simplifier's stage, a cascade's second stage appends its own the same way
//! ([`Partial::append_second`]), and both are decoded straight from the file on resume, so no
//! second copy of either is ever in memory. (Until format 27 the second stage's state went to
//! the writer encoded in a `Vec`: on hydrogen upsampled to 4033^3 with two stages that copy
//! took the run's peak RSS from 257 to 288 MiB; docs/scale.md.) The writer's stage appends the
//! rest once its files are flushed, fills in the lengths, fsyncs the file, renames it and fsyncs
//! the folder.
//!
//! **The end.** Once the output is complete under its temporary name (fsynced), a run that has a
//! checkpoint (or makes them) writes a [`Finished`] record over it, the same way, before it
//! renames the output, writes the run summary and removes the record. A kill before the record
//! leaves the last checkpoint (its files are intact: the output is only renamed after); a kill
//! after it, a state `--resume` finishes from the record alone, computing nothing again: the
//! output was renamed or is renamed then, the summary it holds is written, the record removed.
//! (The output's rename used to come first, then the checkpoint's removal: a kill between them
//! left a checkpoint whose temporary output was gone, so only `--restart`, a whole run again,
//! got out of it.)

use std::fs::File;
use std::hash::Hasher;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use isostream_volume::VolumeSource;
use twox_hash::XxHash64;

use serde::{Deserialize, Serialize, de::DeserializeOwned};

use crate::config::JobConfig;
use crate::error::RunError;

const MAGIC: &[u8; 16] = b"isostream-ckpt\n\0";
/// The first bytes of a [`Finished`] record.
const FINISHED_MAGIC: &[u8; 16] = b"isostream-done\n\0";
/// Bumped whenever the layout of the file or of its sections changes (2: the prune filter's
/// part; 3: the simplifier's section streamed ahead of the rest; 4: the simplifier's
/// pass-through band and a cascade's second simplifier; 5: the guard index's quantized cell
/// entries; 6: the second simplifier's view of the first's resident faces, for the shared
/// budget; 7: the guard's records with their query mark, without boxes; 8: without the mark;
/// 9: vertex flags beside the slot generations; 10: the boundary rule in the simplifier's
/// configuration; 11: the guard's cell entries packed for the branch-free test; 12: the
/// candidate queue in buckets of cost; 13: one contraction evaluator in the simplifier; 14: the
/// data-dependent weight kept with each vertex; 15: the rank spacing kept by the evaluator
/// only; 16: the guard's region of dropped ghosts and its refusal count; 17: vertex positions
/// kept dense beside the slots; 18: the simplifier as a pass-through or a stage of band,
/// decimator and retirer; 19: the guard's work counters; 20: the guard's records filed with
/// room to move; 21: the vertex positions in `f32`, beside the slot generations; 22: the
/// position kept only there, not in the vertex; 23: the time-lag's and priorities' vertex state
/// beside the vertices, kept only by the policies that use it; 24: a vertex's output number
/// without its `Option`); 25: the guard's cells as arrays of keys and of record numbers, its
/// ghosts with their top; 26: the guard's count of records a level instead of their lists;
/// 27: a cascade's second simplifier streamed into a section of its own; 28: vertex attributes
/// beside the vertices; 29: the extraction's largest slab; 30: the sweep's rows and the
/// simplifier's fronts within a slab; 31: a cascade's rear with rows; 32: a free vertex slot's
/// position NaN, read by the dense scan of positions; 33: the guard's cell lists in blocks of
/// one pool; 34: the costs' tie-break by edge length, so the queued costs of a 33 are not this
/// build's; 35: the extraction's count of non-finite attribute values; 36: axis flips applied,
/// so a flipped input's half-written output of a 35 is in other coordinates; 37: the
/// extraction's and the data range's counts of voxels saturated to f32's range; 38: the
/// volume's box in the simplifier's configuration; 39: the first
/// pass's counts, so a resume does not run it again; 40: band depths in slabs as thick as the
/// voxels are wide, so a thin-slab job's older checkpoint is refused by its format, not as made
/// with another configuration).
const FORMAT: u32 = 40;
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
    XxHash64::oneshot(0, bytes)
}

/// Hash of a slice's values as little-endian bytes (the carried slice's check on resume).
pub(crate) fn hash_slice(values: &[f32]) -> u64 {
    let mut h = SliceHasher::default();
    h.add(values);
    h.finish()
}

/// [`hash_slice`] of values given in parts (a slice row by row), never copied: a slice of a
/// gigavoxel volume is tens of MiB, and a copy of it as bytes would be as large.
pub(crate) struct SliceHasher(XxHash64);

impl Default for SliceHasher {
    fn default() -> Self {
        Self(XxHash64::with_seed(0))
    }
}

impl SliceHasher {
    pub fn add(&mut self, values: &[f32]) {
        let mut buf = [0u8; 4096];
        for chunk in values.chunks(buf.len() / 4) {
            for (b, v) in buf.chunks_exact_mut(4).zip(chunk) {
                b.copy_from_slice(&v.to_le_bytes());
            }
            self.0.write(&buf[..4 * chunk.len()]);
        }
    }

    pub fn finish(&self) -> u64 {
        self.0.finish()
    }
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
/// range, the detector and the prune filter (when `min_component_faces` is set) their encoded
/// states, the simplifier the file it began with its state).
pub(crate) struct Cut {
    pub reader: ReaderState,
    pub extract: isostream_extract::ExtractStats,
    pub detect: Vec<u8>,
    /// Empty when the job does not prune.
    pub prune: Vec<u8>,
    /// The checkpoint file, begun by the simplifier with its state (and a cascade's second
    /// simplifier's after it).
    pub simplify: Option<Partial>,
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
            simplify: None,
        })
    }
}

/// What the stages saved at one cut besides the simplifier (see [`Partial`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Parts {
    pub reader: ReaderState,
    pub extract: isostream_extract::ExtractStats,
    pub detect: Vec<u8>,
    pub prune: Vec<u8>,
    pub sink: isostream_smesh::SinkState,
}

/// What the first pass over the volume found that the run depends on: the same job and input
/// give the same counts, so a resumed run takes them from its checkpoint instead of counting
/// again (2.9 s at 511^3, minutes at gigavoxel scale, before the resume did anything).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct FirstPassCounts {
    /// The faces the simplifier receives (extracted, less those pruned): `[output] faces` sets
    /// the rate from them.
    pub kept: u64,
    /// The most faces one slab had: the stage count on large slices
    /// (`JobConfig::counts_slabs_for_stages`) and the budget follow from it.
    pub largest_slab: u64,
}

/// The checkpoint: its last section, and where the simplifiers' lie.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Checkpoint {
    /// [`job_hash`] of the job that saved it.
    pub job: u64,
    pub input: InputIdentity,
    pub slabs_total: u64,
    pub parts: Parts,
    /// The first pass's counts (`None`: the job ran none).
    pub first_pass: Option<FirstPassCounts>,
    /// The simplifier's section in the file (filled in by [`read`]; decoded by
    /// [`decode_section`]).
    #[serde(skip)]
    pub simplify: Section,
    /// A cascade's second simplifier's section (empty without one).
    #[serde(skip)]
    pub simplify_second: Section,
}

/// Where a section lies in the checkpoint file.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Section {
    pub offset: u64,
    pub len: u64,
}

/// What `.NAME.ckpt` holds.
#[derive(Debug)]
pub(crate) enum Saved {
    /// A checkpoint to continue the run from.
    Partway(Box<Checkpoint>),
    /// The record of a run whose output was complete.
    Finished(Box<Finished>),
}

impl Saved {
    pub fn percent(&self) -> f64 {
        match self {
            Saved::Partway(c) => c.percent(),
            Saved::Finished(_) => 100.0,
        }
    }

    /// The temporary files it refers to (a resume needs them; never the output itself).
    fn files(&self) -> Vec<PathBuf> {
        match self {
            Saved::Partway(c) => c.parts.sink.files().map(Path::to_path_buf).collect(),
            Saved::Finished(f) => std::iter::once(&f.temp)
                .chain(&f.scratch)
                .cloned()
                .collect(),
        }
    }
}

/// What a run writes over its checkpoint once its output is complete under its temporary name,
/// before it renames it: from then on nothing is left to compute, and `--resume` after a kill
/// does what is left (the rename, the run summary, this record's removal) from it alone. JSON
/// (the summary is read back whole; bincode cannot read back its left-out fields), after
/// [`FINISHED_MAGIC`] and before an xxHash64 of it.
#[derive(Debug, Serialize, Deserialize)]
pub(crate) struct Finished {
    /// [`job_hash`] of the job that wrote it.
    pub job: u64,
    pub input: InputIdentity,
    /// The complete output under its temporary name.
    pub temp: PathBuf,
    /// The scratch files it was assembled from (PLY, GLB), removed once it is in place.
    pub scratch: Vec<PathBuf>,
    /// Its size. Once renamed, the output of that size is this run's: the same job and input
    /// give the same bytes (a resume checks both first), so even an earlier run's output of
    /// this job would be it.
    pub bytes: u64,
    pub summary: crate::RunSummary,
}

impl Finished {
    /// Whether the output is under its final name already (a kill after the rename) or still
    /// under its temporary one; neither, in words.
    fn renamed(&self, output: &Path) -> Result<bool, String> {
        let size = |p: &Path| {
            std::fs::metadata(p)
                .ok()
                .filter(|m| m.is_file())
                .map(|m| m.len())
        };
        if size(&self.temp) == Some(self.bytes) {
            return Ok(false);
        }
        if size(output) == Some(self.bytes) {
            return Ok(true);
        }
        Err(format!(
            "the run had finished its output, but neither its temporary file {} nor {} holds its {} bytes any more",
            self.temp.display(),
            output.display(),
            self.bytes
        ))
    }

    /// Puts the output under its final name, unless it is already, and removes the scratch
    /// files left (`path`: the record, named when the output is gone).
    pub fn place(&self, path: &Path, output: &Path) -> Result<(), RunError> {
        match self.renamed(output) {
            Ok(true) => {}
            Ok(false) => isostream_smesh::put_in_place(&self.temp, output)?,
            Err(reason) => {
                return Err(RunError::Checkpoint {
                    path: path.to_path_buf(),
                    reason,
                });
            }
        }
        for f in &self.scratch {
            // Best effort, as the sink's own removal: one left is reported as stale.
            let _ = std::fs::remove_file(f);
        }
        Ok(())
    }
}

/// Writes `finished` over the checkpoint `path` (or where none is yet), atomically and durably.
pub(crate) fn write_finished(path: &Path, finished: &Finished) -> Result<(), RunError> {
    let fail = |e: std::io::Error| write_error(path, e);
    let json = serde_json::to_vec(finished).map_err(|e| fail(std::io::Error::other(e)))?;
    let mut tmp = temp_beside(path).map_err(fail)?;
    let file = tmp.as_file_mut();
    file.write_all(FINISHED_MAGIC)
        .and_then(|()| file.write_all(&json))
        .and_then(|()| file.write_all(&hash(&json).to_le_bytes()))
        .map_err(fail)?;
    put_durably(tmp, path).map_err(fail)
}

/// A temporary file next to the checkpoint `path`, `.NAME.ckpt.XXXXXX.tmp`: recognised as stale
/// by `stale_temp_files`.
fn temp_beside(path: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    let prefix = format!(
        "{}.",
        path.file_name().unwrap_or_default().to_string_lossy()
    );
    isostream_smesh::output_builder(&prefix).tempfile_in(dir_of(path))
}

/// Makes `tmp` the file `path`: fsync, rename, fsync of the folder.
fn put_durably(tmp: tempfile::NamedTempFile, path: &Path) -> std::io::Result<()> {
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    #[cfg(unix)]
    File::open(dir_of(path)).and_then(|d| d.sync_all())?;
    Ok(())
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
    job.simplify = job.simplify.as_written_before();
    hash(&serde_json::to_vec(&job).unwrap_or_default())
}

/// What identifies the input: the source's description, its grid, the size and modification
/// time of every file the job names, and a hash of the stored values of slice 0
/// (`VolumeSource::identity_values`: an upsampled input's source slice, not the fine one; with
/// the carried slice's hash, the data is sampled where the run starts again).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct InputIdentity {
    pub describe: String,
    pub dims: [u64; 3],
    pub files: Vec<(PathBuf, u64, u128)>,
    pub first_slice: u64,
}

impl InputIdentity {
    /// The identity of `job`'s input as `source` reads it now: what a run saves and what a
    /// resume ([`verify`]) and `isostream validate` ([`checkpoint_note`]) compare with it.
    pub fn read(job: &JobConfig, source: &mut dyn VolumeSource) -> Result<Self, RunError> {
        let first_slice = hash_slice(&source.identity_values(0)?);
        Ok(Self::of(
            job,
            source.describe(),
            source.grid().dims,
            first_slice,
        ))
    }

    fn of(job: &JobConfig, describe: String, dims: [u64; 3], first_slice: u64) -> Self {
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

/// A checkpoint file being written: begun by the simplifier's stage with its state, finished by
/// the writer's stage with the rest. Dropped unfinished (a failed or cancelled run), its
/// temporary file is removed.
pub(crate) struct Partial {
    path: PathBuf,
    tmp: tempfile::NamedTempFile,
    hasher: XxHash64,
    /// Length of the simplifier's section.
    simplify: u64,
    /// Length of a cascade's second simplifier's section (0 without one).
    second: u64,
}

/// Writes through, hashing and counting what passes.
struct Hashing<W> {
    inner: W,
    hasher: XxHash64,
    len: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hasher.write(&buf[..n]);
        self.len += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Bytes before the sections: magic, format, version, the three sections' lengths.
fn head(lengths: [u64; 3]) -> Vec<u8> {
    let mut head = Vec::with_capacity(64);
    head.extend_from_slice(MAGIC);
    head.extend_from_slice(&FORMAT.to_le_bytes());
    head.push(VERSION.len() as u8);
    head.extend_from_slice(VERSION.as_bytes());
    for len in lengths {
        head.extend_from_slice(&len.to_le_bytes());
    }
    head
}

impl Partial {
    /// Begins the checkpoint `path` under a temporary name next to it, with the simplifier's
    /// state `simplify` encoded straight into the file.
    pub fn begin<T: Serialize + ?Sized>(path: &Path, simplify: &T) -> Result<Self, RunError> {
        let mut tmp = temp_beside(path).map_err(|e| write_error(path, e))?;
        // The lengths are filled in by `finish`.
        tmp.write_all(&head([0; 3]))
            .map_err(|e| write_error(path, e))?;
        let (hasher, simplify) = encode_hashed(tmp.as_file_mut(), XxHash64::with_seed(0), simplify)
            .map_err(|e| write_error(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            tmp,
            hasher,
            simplify,
            second: 0,
        })
    }

    /// Bytes of the simplifier's section.
    pub fn simplify_len(&self) -> u64 {
        self.simplify
    }

    /// Appends a cascade's second simplifier's state `second`, encoded straight into the file
    /// like the first's; returns its bytes.
    pub fn append_second<T: Serialize + ?Sized>(&mut self, second: &T) -> Result<u64, RunError> {
        let hasher = std::mem::replace(&mut self.hasher, XxHash64::with_seed(0));
        let (hasher, len) = encode_hashed(self.tmp.as_file_mut(), hasher, second)
            .map_err(|e| write_error(&self.path, e))?;
        self.hasher = hasher;
        self.second += len;
        Ok(len)
    }

    /// Appends the rest, the hash and the lengths, then makes the file the checkpoint atomically
    /// (fsync, rename, fsync of the folder). Returns the file's length.
    pub fn finish(self, ckpt: &Checkpoint) -> Result<u64, RunError> {
        let Partial {
            path,
            mut tmp,
            hasher,
            simplify,
            second,
        } = self;
        let fail = |e: std::io::Error| write_error(&path, e);
        let (hasher, rest) = encode_hashed(tmp.as_file_mut(), hasher, ckpt).map_err(fail)?;
        let file = tmp.as_file_mut();
        file.write_all(&hasher.finish().to_le_bytes())
            .map_err(fail)?;
        file.seek(SeekFrom::Start(0)).map_err(fail)?;
        let head = head([simplify, second, rest]);
        file.write_all(&head).map_err(fail)?;
        put_durably(tmp, &path).map_err(fail)?;
        Ok(head.len() as u64 + simplify + second + rest + 8)
    }
}

/// Encodes `value` at the end of `file`, buffered, through `hasher`; returns the hasher and the
/// bytes written.
fn encode_hashed<T: Serialize + ?Sized>(
    file: &mut File,
    hasher: XxHash64,
    value: &T,
) -> std::io::Result<(XxHash64, u64)> {
    file.seek(SeekFrom::End(0))?;
    let mut w = Hashing {
        inner: BufWriter::with_capacity(1 << 16, file),
        hasher,
        len: 0,
    };
    // bincode wraps the writer's error: its Display was the Debug of the io::Error ("Io {
    // inner: Os { code: 28, kind: StorageFull, .. }, index: 720866 }").
    bincode::serde::encode_into_std_write(value, &mut w, config()).map_err(|e| match e {
        bincode::error::EncodeError::Io { inner, .. } => inner,
        other => std::io::Error::other(other.to_string()),
    })?;
    w.flush()?;
    Ok((w.hasher, w.len))
}

/// A checkpoint not written; the one saved before (a failed write never touches it) is named
/// with its slab, read back now: this is the error path, once per run.
fn write_error(path: &Path, source: std::io::Error) -> RunError {
    RunError::CheckpointWrite {
        path: path.to_path_buf(),
        source,
        kept: match read(path) {
            Ok(Saved::Partway(c)) => Some((c.slabs_done(), c.slabs_total)),
            _ => None,
        },
    }
}

/// Reads and checks a checkpoint: magic, format, crate version, lengths, hash (streamed over the
/// file), then decodes the rest; the simplifier's section is decoded later, from the file
/// ([`decode_section`]). Or a [`Finished`] record: magic, hash, JSON.
pub(crate) fn read(path: &Path) -> Result<Saved, RunError> {
    let cannot = |source| RunError::CheckpointIo {
        path: path.to_path_buf(),
        what: "read",
        source,
    };
    let mut file = File::open(path).map_err(cannot)?;
    let size = file.metadata().map_err(cannot)?.len();
    // The longest head: magic, format, a version of 255 bytes, three lengths.
    let mut bytes = Vec::new();
    (&mut file)
        .take(16 + 4 + 1 + 255 + 24)
        .read_to_end(&mut bytes)
        .map_err(cannot)?;
    let refuse = |reason: String| RunError::Checkpoint {
        path: path.to_path_buf(),
        reason,
    };
    let truncated = || refuse(format!("truncated checkpoint ({size} bytes)"));
    if bytes.starts_with(FINISHED_MAGIC) {
        let mut all = Vec::new();
        file.seek(SeekFrom::Start(0))
            .and_then(|_| file.read_to_end(&mut all))
            .map_err(cannot)?;
        let body = &all[FINISHED_MAGIC.len()..];
        let (json, sum) = body
            .split_at_checked(body.len().wrapping_sub(8))
            .ok_or_else(truncated)?;
        if sum != hash(json).to_le_bytes() {
            return Err(corrupt(path, "checksum mismatch"));
        }
        return serde_json::from_slice(json)
            .map(|f| Saved::Finished(Box::new(f)))
            .map_err(|e| corrupt(path, &e.to_string()));
    }
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
    let (simplify, rest) = take::<8>(rest).ok_or_else(truncated)?;
    let (second, rest) = take::<8>(rest).ok_or_else(truncated)?;
    let (others, _) = take::<8>(rest).ok_or_else(truncated)?;
    let [simplify, second, others] = [simplify, second, others].map(u64::from_le_bytes);
    let head = head([0; 3]).len() as u64;
    let end = head
        .checked_add(simplify)
        .and_then(|x| x.checked_add(second))
        .and_then(|x| x.checked_add(others))
        .ok_or_else(|| corrupt(path, "section lengths"))?;
    match size.checked_sub(end) {
        None | Some(0..8) => return Err(truncated()),
        Some(8) => {}
        Some(_) => return Err(corrupt(path, "bytes after the end")),
    }
    // The hash of the sections, streamed: the simplifiers' may be tens of MiB.
    file.seek(SeekFrom::Start(head)).map_err(cannot)?;
    let mut sections = Hashing {
        inner: std::io::sink(),
        hasher: XxHash64::with_seed(0),
        len: 0,
    };
    std::io::copy(&mut (&mut file).take(end - head), &mut sections).map_err(cannot)?;
    let mut sum = [0u8; 8];
    file.read_exact(&mut sum).map_err(cannot)?;
    if sections.len != end - head || u64::from_le_bytes(sum) != sections.hasher.finish() {
        return Err(corrupt(path, "checksum mismatch"));
    }
    let mut body = Vec::new();
    file.seek(SeekFrom::Start(head + simplify + second))
        .and_then(|_| (&mut file).take(others).read_to_end(&mut body))
        .map_err(cannot)?;
    let mut ckpt: Checkpoint = decode(path, &body)?;
    ckpt.simplify = Section {
        offset: head,
        len: simplify,
    };
    ckpt.simplify_second = Section {
        offset: head + simplify,
        len: second,
    };
    Ok(Saved::Partway(Box::new(ckpt)))
}

/// Decodes a simplifier's section of a checkpoint [`read`] checked, straight from the file.
pub(crate) fn decode_section<T: DeserializeOwned>(
    path: &Path,
    section: Section,
) -> Result<T, RunError> {
    let Section { offset, len } = section;
    let mut file = File::open(path).map_err(|source| RunError::CheckpointIo {
        path: path.to_path_buf(),
        what: "read",
        source,
    })?;
    file.seek(SeekFrom::Start(offset))
        .map_err(|e| corrupt(path, &e.to_string()))?;
    let mut section = BufReader::with_capacity(1 << 16, file.take(len));
    bincode::serde::decode_from_std_read(&mut section, config())
        .map_err(|e| corrupt(path, &e.to_string()))
}

fn take<const N: usize>(bytes: &[u8]) -> Option<([u8; N], &[u8])> {
    let head = bytes.get(..N)?;
    Some((head.try_into().ok()?, &bytes[N..]))
}

/// Checks that `saved` belongs to this job and input.
pub(crate) fn verify(
    path: &Path,
    saved: &Saved,
    job: &JobConfig,
    input: &InputIdentity,
) -> Result<(), RunError> {
    let (saved_job, saved_input) = match saved {
        Saved::Partway(c) => (c.job, &c.input),
        Saved::Finished(f) => (f.job, &f.input),
    };
    if saved_job != job_hash(job) {
        return Err(RunError::ResumeMismatch {
            path: path.to_path_buf(),
            what: "the job file changed since the checkpoint".into(),
        });
    }
    if let Some(diff) = saved_input.difference(input) {
        return Err(RunError::ResumeMismatch {
            path: path.to_path_buf(),
            what: format!("the input changed since the checkpoint ({diff})"),
        });
    }
    Ok(())
}

/// What `isostream validate` says of the checkpoint an interrupted run of `job`'s output left
/// (`None` without one): `validate` checks the job, not the command, so this is a note, but
/// `run` refuses to start while it is there, and only the run's own checks ([`read`], then
/// [`verify`] against the job and the input `source` reads now, and for a [`Finished`] record
/// whether its output is still there) say whether `--resume` can continue it or only
/// `--restart` will do.
pub fn checkpoint_note(
    job: &JobConfig,
    source: &mut dyn VolumeSource,
) -> Result<Option<String>, RunError> {
    let path = path_for(&job.output.path);
    if !path.exists() {
        return Ok(None);
    }
    let found = |at: String| {
        format!(
            "a checkpoint of an interrupted run of this output exists ({at}{})",
            path.display()
        )
    };
    let saved = match read(&path) {
        Ok(saved) => saved,
        Err(RunError::Checkpoint { reason, .. }) => {
            return Ok(Some(format!(
                "{} but cannot be resumed ({reason}); `run` needs --restart",
                found(String::new())
            )));
        }
        Err(e) => return Err(e),
    };
    let input = InputIdentity::read(job, source)?;
    let verified = verify(&path, &saved, job, &input);
    let (found, usable) = match &saved {
        Saved::Partway(c) => (
            found(format!("{:.0} %, ", c.percent())),
            match c.parts.sink.check_files() {
                Err(e) if crate::sink::unusable(&e) => {
                    Err(format!("a file it needs cannot be used ({e})"))
                }
                _ => Ok("continue it (the job and its input are unchanged)"),
            },
        ),
        Saved::Finished(f) => (
            found("100 %: the output was written, the run stopped before its last steps, ".into()),
            f.renamed(&job.output.path).map(|_| {
                "finish it without computing anything again (the job and its input are unchanged)"
            }),
        ),
    };
    Ok(Some(match (verified, usable) {
        (Ok(()), Ok(what)) => {
            format!("{found}; `run` needs --resume to {what} or --restart to start over")
        }
        (Err(RunError::ResumeMismatch { what, .. }), _) | (Ok(()), Err(what)) => {
            format!("{found}, but {what}: `run` needs --restart (it starts over)")
        }
        (Err(e), _) => return Err(e),
    }))
}

/// Removes a checkpoint and the temporary files it refers to (a run starting over). A
/// checkpoint that cannot be read is removed alone.
pub(crate) fn discard(path: &Path) -> Result<(), RunError> {
    if !path.exists() {
        return Ok(());
    }
    if let Ok(saved) = read(path) {
        for f in saved.files() {
            let _ = std::fs::remove_file(f);
        }
    }
    std::fs::remove_file(path).map_err(|source| RunError::CheckpointIo {
        path: path.to_path_buf(),
        what: "remove",
        source,
    })
}

/// Removes the checkpoint of a completed run (its [`Finished`] record, or a checkpoint whose
/// temporary files became the output or were removed by the sink).
pub(crate) fn remove(path: &Path) -> Result<(), RunError> {
    match std::fs::remove_file(path) {
        Err(source) if source.kind() != std::io::ErrorKind::NotFound => {
            Err(RunError::CheckpointIo {
                path: path.to_path_buf(),
                what: "remove (the run completed)",
                source,
            })
        }
        _ => Ok(()),
    }
}

/// The temporary files a readable checkpoint of `output` refers to (not stale: a resume needs
/// them).
pub(crate) fn referenced_files(output: &Path) -> Vec<PathBuf> {
    read(&path_for(output))
        .map(|saved| saved.files())
        .unwrap_or_default()
}

/// What a resume of `output` needs: its checkpoint and the files it refers to, and the output
/// itself after a [`Finished`] record (it may be renamed already); empty when there is no
/// readable checkpoint.
pub fn resumable_files(output: &Path) -> Vec<PathBuf> {
    let path = path_for(output);
    match read(&path) {
        Ok(saved) => {
            let finished = matches!(saved, Saved::Finished(_)).then(|| output.to_path_buf());
            std::iter::once(path)
                .chain(saved.files())
                .chain(finished)
                .collect()
        }
        Err(_) => Vec::new(),
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

    /// A checkpoint that cannot be read (here a folder) is a file to fix, not one to throw away
    /// with `--restart` (which would fail to remove it too): its own error, exit 1.
    #[test]
    fn an_unreadable_checkpoint_is_an_io_error() {
        let dir = tempfile::tempdir().unwrap();
        let e = read(dir.path()).unwrap_err();
        assert!(
            matches!(e, RunError::CheckpointIo { what: "read", .. }),
            "{e:?}"
        );
        let msg = e.to_string();
        assert!(
            msg.contains("cannot read the checkpoint") && !msg.contains("--restart"),
            "{msg}"
        );
    }

    /// A checkpoint of a build before keys could be left out holds the hash of the job with
    /// them written (`initial_rate = 0.5`, ...): the same job with them left out hashes alike,
    /// so that checkpoint still resumes (it was refused as "the job file changed").
    #[test]
    fn keys_left_out_hash_as_their_defaults_written() {
        let job = |simplify: &str| {
            let text = format!(
                "[input]\nshape = \"sphere\"\nsize = [16, 16, 16]\n[extract]\niso = 0.0\n[simplify]\n{simplify}\n[output]\npath = \"o.smb\"\n"
            );
            JobConfig::parse(&text, std::path::Path::new("job.toml")).unwrap()
        };
        let written = "rate = 0.1\ninitial_rate = 0.5\nretire_lag = 8\ntime_lag = true\nisotropy = 0.0\npriority = \"geometric\"";
        assert_eq!(job_hash(&job("rate = 0.1")), job_hash(&job(written)));
        assert_ne!(job_hash(&job("rate = 0.1")), job_hash(&job("rate = 0.2")));
    }

    /// An upsampled input is identified by its source's slice 0, not by the fine one: a sphere
    /// of 12 upsampled 100000 x 100000 hashed 1.2e12 fine voxels before any stage started, deaf
    /// to SIGTERM. The factors still tell two inputs apart (`describe`, `dims`).
    #[test]
    fn an_upsampled_input_is_identified_by_its_source_slices() {
        let job = |upsample: &str| {
            let text = format!(
                "[input]\nshape = \"sphere\"\nsize = [12, 12, 12]\nupsample = {upsample}\n[extract]\niso = 0.0\n[output]\npath = \"o.smb\"\n"
            );
            JobConfig::parse(&text, std::path::Path::new("job.toml")).unwrap()
        };
        let identity = |job: &JobConfig| {
            InputIdentity::read(job, crate::open_source(&job.input).unwrap().as_mut()).unwrap()
        };
        let huge = job("[100000, 100000, 1]");
        let mut sphere = crate::open_source(&job("[1, 1, 1]").input).unwrap();
        let mut slice0 = vec![0f32; sphere.grid().slice_len()];
        sphere.read_slice(0, &mut slice0).unwrap();
        assert_eq!(identity(&job("[2, 2, 1]")).first_slice, hash_slice(&slice0));
        let started = std::time::Instant::now();
        let id = identity(&huge);
        assert!(started.elapsed().as_secs() < 5, "{:?}", started.elapsed());
        assert_eq!(id.first_slice, hash_slice(&slice0));
        assert!(
            id.difference(&identity(&job("[100000, 99999, 1]")))
                .is_some()
        );
    }

    /// bincode's error around the disk's was shown as Debug; the disk's own error comes out,
    /// and the message says to resume, not to restart.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_full_disk_is_the_disk_s_error_and_the_fix_is_to_resume() {
        let mut full = File::options().write(true).open("/dev/full").unwrap();
        let e = encode_hashed(&mut full, XxHash64::with_seed(0), &vec![7u64; 1 << 16]).unwrap_err();
        assert_eq!(e.kind(), std::io::ErrorKind::StorageFull, "{e}");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(".o.smb.ckpt");
        let msg = write_error(&path, e).to_string();
        assert!(
            msg.ends_with(
                ".o.smb.ckpt: cannot write the checkpoint: No space left on device (os error 28); free space on that disk, then run with --resume (no checkpoint was saved before: it starts from the beginning)"
            ),
            "{msg}"
        );
    }

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
                sink: sink_state(),
            },
            first_pass: Some(FirstPassCounts {
                kept: 12,
                largest_slab: 4,
            }),
            simplify: Section::default(),
            simplify_second: Section::default(),
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
        let mut partial = Partial::begin(&path, &vec![4u8; 100]).unwrap();
        assert_eq!(partial.simplify_len(), 108);
        assert_eq!(partial.append_second(&vec![5u8; 10]).unwrap(), 18);
        let len = partial.finish(&sample()).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), len);
        let Saved::Partway(back) = read(&path).unwrap() else {
            panic!("not a checkpoint");
        };
        assert_eq!(back.percent(), 60.0);
        assert_eq!(back.parts.detect, vec![1, 2, 3]);
        assert_eq!(back.first_pass, sample().first_pass);
        let simplify: Vec<u8> = decode_section(&path, back.simplify).unwrap();
        assert_eq!(simplify, vec![4; 100]);
        let second: Vec<u8> = decode_section(&path, back.simplify_second).unwrap();
        assert_eq!(second, vec![5; 10]);
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
