//! Writes small Zarr v3 stores from Rust (no zarr-python): zarr.json plus chunk files encoded
//! with the codecs under test, so the reader is checked against an independent encoder.

use flate2::Compression;
use flate2::write::GzEncoder;
use serde_json::{Value, json};
use std::io::Write;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compress {
    None,
    Gzip,
    Zstd,
}

#[derive(Debug, Clone)]
pub struct Shard {
    pub inner: Vec<u64>,
    pub index_at_end: bool,
}

/// How to write an array. Shapes and chunk shapes are in Zarr order (z, y, x last).
#[derive(Debug, Clone)]
pub struct Spec {
    pub shape: Vec<u64>,
    /// The chunk shape, or the shard shape when `shard` is set.
    pub chunks: Vec<u64>,
    pub dtype: &'static str,
    pub endian: &'static str,
    /// chunk_key_encoding name and separator.
    pub keys: (&'static str, &'static str),
    pub fill: f64,
    pub transpose: Option<Vec<usize>>,
    pub compress: Compress,
    pub crc: bool,
    pub shard: Option<Shard>,
}

impl Spec {
    pub fn new(shape: &[u64], chunks: &[u64]) -> Spec {
        Spec {
            shape: shape.to_vec(),
            chunks: chunks.to_vec(),
            dtype: "uint8",
            endian: "little",
            keys: ("default", "/"),
            fill: 0.0,
            transpose: None,
            compress: Compress::None,
            crc: false,
            shard: None,
        }
    }

    fn chain(&self) -> Vec<Value> {
        let mut c = Vec::new();
        if let Some(order) = &self.transpose {
            c.push(json!({"name": "transpose", "configuration": {"order": order}}));
        }
        c.push(json!({"name": "bytes", "configuration": {"endian": self.endian}}));
        match self.compress {
            Compress::None => {}
            Compress::Gzip => c.push(json!({"name": "gzip", "configuration": {"level": 1}})),
            Compress::Zstd => {
                c.push(json!({"name": "zstd", "configuration": {"level": 1, "checksum": false}}))
            }
        }
        if self.crc {
            c.push(json!({"name": "crc32c"}));
        }
        c
    }

    pub fn metadata(&self) -> Value {
        let codecs = match &self.shard {
            None => self.chain(),
            Some(s) => vec![json!({
                "name": "sharding_indexed",
                "configuration": {
                    "chunk_shape": s.inner,
                    "codecs": self.chain(),
                    "index_codecs": [
                        {"name": "bytes", "configuration": {"endian": "little"}},
                        {"name": "crc32c"}
                    ],
                    "index_location": if s.index_at_end { "end" } else { "start" },
                }
            })],
        };
        let fill = if self.fill.is_nan() {
            json!("NaN")
        } else if self.dtype.starts_with("float") {
            json!(self.fill)
        } else {
            json!(self.fill as i64)
        };
        json!({
            "zarr_format": 3,
            "node_type": "array",
            "shape": self.shape,
            "data_type": self.dtype,
            "chunk_grid": {"name": "regular", "configuration": {"chunk_shape": self.chunks}},
            "chunk_key_encoding": {"name": self.keys.0, "configuration": {"separator": self.keys.1}},
            "fill_value": fill,
            "codecs": codecs,
            "attributes": {},
        })
    }

    pub fn key(&self, coords: &[u64]) -> String {
        let sep = self.keys.1;
        let joined: Vec<String> = coords.iter().map(u64::to_string).collect();
        match self.keys.0 {
            "v2" => joined.join(sep),
            _ => format!("c{sep}{}", joined.join(sep)),
        }
    }

    /// Encodes the chunk at grid coordinates `g` of shape `cs` (edge chunks padded with fill).
    fn encode_chunk(&self, g: &[u64], cs: &[u64], value: &dyn Fn(&[u64]) -> f64) -> Vec<u8> {
        let rank = cs.len();
        let order: Vec<usize> = self.transpose.clone().unwrap_or((0..rank).collect());
        let enc_shape: Vec<u64> = order.iter().map(|&a| cs[a]).collect();
        let mut bytes = Vec::new();
        for e in indices(&enc_shape) {
            let mut global = vec![0u64; rank];
            for i in 0..rank {
                global[order[i]] = g[order[i]] * cs[order[i]] + e[i];
            }
            let inside = global.iter().zip(&self.shape).all(|(i, n)| i < n);
            let v = if inside { value(&global) } else { self.fill };
            bytes.extend(encode_value(self.dtype, self.endian, v));
        }
        let mut out = match self.compress {
            Compress::None => bytes,
            Compress::Gzip => gzip(&bytes),
            Compress::Zstd => ruzstd::encoding::compress_to_vec(
                bytes.as_slice(),
                ruzstd::encoding::CompressionLevel::Fastest,
            ),
        };
        if self.crc {
            let c = crc32c(&out);
            out.extend(c.to_le_bytes());
        }
        out
    }
}

/// Writes the array to `dir`; chunks (inner chunks when sharded) whose grid coordinates fail
/// `keep` are left out, so they read as the fill value.
pub fn write(
    dir: &Path,
    spec: &Spec,
    value: &dyn Fn(&[u64]) -> f64,
    keep: &dyn Fn(&[u64]) -> bool,
) {
    std::fs::create_dir_all(dir).unwrap();
    write_json(&dir.join("zarr.json"), &spec.metadata());
    let grid: Vec<u64> = spec
        .shape
        .iter()
        .zip(&spec.chunks)
        .map(|(n, c)| n.div_ceil(*c))
        .collect();
    for g in indices(&grid) {
        let bytes = match &spec.shard {
            None if !keep(&g) => continue,
            None => spec.encode_chunk(&g, &spec.chunks, value),
            Some(s) => match encode_shard(spec, s, &g, value, keep) {
                Some(b) => b,
                None => continue,
            },
        };
        let path = dir.join(spec.key(&g));
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, bytes).unwrap();
    }
}

/// A shard: its kept inner chunks back to back, then (or before) the index with its crc32c.
fn encode_shard(
    spec: &Spec,
    s: &Shard,
    g: &[u64],
    value: &dyn Fn(&[u64]) -> f64,
    keep: &dyn Fn(&[u64]) -> bool,
) -> Option<Vec<u8>> {
    let per: Vec<u64> = spec
        .chunks
        .iter()
        .zip(&s.inner)
        .map(|(a, b)| a / b)
        .collect();
    let n: u64 = per.iter().product();
    let index_len = 16 * n + 4;
    let base = if s.index_at_end { 0 } else { index_len };
    let (mut data, mut index) = (Vec::new(), Vec::new());
    for i in indices(&per) {
        let inner_g: Vec<u64> = g
            .iter()
            .zip(&per)
            .zip(&i)
            .map(|((g, p), i)| g * p + i)
            .collect();
        let inside = inner_g
            .iter()
            .zip(&s.inner)
            .zip(&spec.shape)
            .all(|((g, c), n)| g * c < *n);
        if !inside || !keep(&inner_g) {
            index.extend(u64::MAX.to_le_bytes());
            index.extend(u64::MAX.to_le_bytes());
            continue;
        }
        let chunk = spec.encode_chunk(&inner_g, &s.inner, value);
        index.extend((base + data.len() as u64).to_le_bytes());
        index.extend((chunk.len() as u64).to_le_bytes());
        data.extend(chunk);
    }
    if data.is_empty() {
        return None;
    }
    let c = crc32c(&index);
    index.extend(c.to_le_bytes());
    Some(if s.index_at_end {
        [data, index].concat()
    } else {
        [index, data].concat()
    })
}

pub fn write_json(path: &Path, v: &Value) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, serde_json::to_vec_pretty(v).unwrap()).unwrap();
}

/// An OME-Zarr v0.5 group at `dir` whose levels are the arrays written to `dir/<path>`, each with
/// its own scale; the dataset translation is `shift`.
pub fn write_ome_group(dir: &Path, levels: &[(&str, [f64; 3])], shift: [f64; 3], rank: usize) {
    let pad = |v: [f64; 3], one: f64| {
        let mut all = vec![one; rank - 3];
        all.extend(v);
        all
    };
    let datasets: Vec<Value> = levels
        .iter()
        .map(|(path, scale)| {
            json!({"path": path, "coordinateTransformations": [
                {"type": "scale", "scale": pad(*scale, 1.0)},
                {"type": "translation", "translation": pad(shift, 0.0)},
            ]})
        })
        .collect();
    let axes: Vec<Value> = ["t", "c", "z", "y", "x"][5 - rank..]
        .iter()
        .map(|n| json!({"name": n}))
        .collect();
    write_json(
        &dir.join("zarr.json"),
        &json!({
            "zarr_format": 3,
            "node_type": "group",
            "attributes": {"ome": {"version": "0.5", "multiscales": [
                {"name": "test", "axes": axes, "datasets": datasets}
            ]}},
        }),
    );
}

/// All multi-indices of `shape` in C order.
pub fn indices(shape: &[u64]) -> Vec<Vec<u64>> {
    let mut out = Vec::new();
    let total: u64 = shape.iter().product();
    for mut k in 0..total {
        let mut idx = vec![0u64; shape.len()];
        for a in (0..shape.len()).rev() {
            idx[a] = k % shape[a];
            k /= shape[a];
        }
        out.push(idx);
    }
    out
}

pub fn encode_value(dtype: &str, endian: &str, v: f64) -> Vec<u8> {
    macro_rules! enc {
        ($t:ty) => {
            if endian == "big" {
                (v as $t).to_be_bytes().to_vec()
            } else {
                (v as $t).to_le_bytes().to_vec()
            }
        };
    }
    match dtype {
        "int8" => enc!(i8),
        "uint8" => enc!(u8),
        "int16" => enc!(i16),
        "uint16" => enc!(u16),
        "int32" => enc!(i32),
        "uint32" => enc!(u32),
        "int64" => enc!(i64),
        "uint64" => enc!(u64),
        "float32" => enc!(f32),
        "float64" => enc!(f64),
        other => panic!("no dtype {other}"),
    }
}

pub fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Bitwise CRC-32C, independent of the reader's table-driven one.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ 0x82F6_3B78
            } else {
                c >> 1
            };
        }
    }
    !c
}
