//! Store metadata: finding the array in a store (a plain array, a group with a child named by the
//! job, or an OME-Zarr multiscale group) and checking everything the reader relies on.
//!
//! Zarr v3 nodes are a `zarr.json`; Zarr v2 nodes a `.zarray` (array) or a `.zgroup` with its
//! attributes in `.zattrs`. OME-Zarr v0.5 puts `multiscales` under `attributes.ome` in a v3
//! group, v0.4 at the top of a v2 group's `.zattrs`; the object is the same, and one function
//! ([`group`]) reads both. A store may mix the two (each node says what it is).

use super::codec::{self, Codecs};
use super::dtype::ZType;
use super::json::J;
use crate::VolumeError;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// The array to read and what the store says about it.
#[derive(Debug)]
pub(crate) struct ArrayMeta {
    /// The array's directory: chunk keys are relative to it.
    pub dir: PathBuf,
    /// Zarr order: the last axis varies fastest. Axes before the last three have size 1.
    pub shape: Vec<u64>,
    pub chunk_shape: Vec<u64>,
    pub ztype: ZType,
    pub fill: f32,
    /// The fill value was a finite float64 beyond f32's range, saturated to `±f32::MAX`.
    pub fill_saturated: bool,
    pub keys: KeyEncoding,
    pub codecs: Codecs,
    /// Voxel size and position in x, y, z order, from OME-Zarr coordinate transformations.
    pub spacing: Option<[f64; 3]>,
    pub origin: Option<[f64; 3]>,
}

/// `chunk_key_encoding`: where the chunk with grid coordinates (i, j, k) is stored.
#[derive(Debug, Clone, Copy)]
pub(crate) struct KeyEncoding {
    /// "v2" keys are `i.j.k`; "default" keys are `c/i/j/k`.
    v2: bool,
    separator: char,
}

impl KeyEncoding {
    /// The chunk file of grid coordinates `coords`, relative to the array directory.
    pub(crate) fn key(&self, coords: &[u64]) -> String {
        let sep = self.separator.to_string();
        let joined = coords
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(&sep);
        if self.v2 {
            joined
        } else {
            format!("c{sep}{joined}")
        }
    }
}

/// Reads the node at `dir` and returns the array to stream: the node itself, the child named
/// `wanted` of a plain group, or the multiscale level `wanted` (default: the first, full
/// resolution) of an OME-Zarr group.
pub(crate) fn resolve(dir: &Path, wanted: Option<&str>) -> Result<ArrayMeta, VolumeError> {
    node(dir, wanted, 0)
}

/// How many groups a lookup may pass through before reaching its array. A store needs two at
/// most (a plain group naming an OME-Zarr group, whose dataset is an array); dataset paths that
/// lead back up (`..`) or round in a loop would otherwise recurse until the stack overflows.
const MAX_GROUPS: usize = 8;

/// Whether `dir` is a Zarr v2 node: it has `.zarray` or `.zgroup` and no `zarr.json`.
fn is_v2(dir: &Path) -> bool {
    !dir.join("zarr.json").exists() && [".zarray", ".zgroup"].iter().any(|f| dir.join(f).is_file())
}

/// [`resolve`] for a node reached through `depth` groups.
fn node(dir: &Path, wanted: Option<&str>, depth: usize) -> Result<ArrayMeta, VolumeError> {
    let v2 = is_v2(dir);
    let file = match (v2, dir.join(".zarray").is_file()) {
        (false, _) => dir.join("zarr.json"),
        (true, true) => dir.join(".zarray"),
        (true, false) => dir.join(".zgroup"),
    };
    let doc = read_json(&file)?;
    let root = J::root(&file, &doc);
    if depth > MAX_GROUPS {
        return Err(root.problem(&format!(
            "reached through more than {MAX_GROUPS} Zarr groups; the dataset or array paths loop, and must name an array"
        )));
    }
    if v2 {
        return node_v2(dir, &root, wanted, depth);
    }
    let format = root.get("zarr_format");
    if format.value.as_u64() != Some(3) {
        return Err(
            format.err("3 (a zarr.json is Zarr v3; Zarr v2 metadata is a .zarray or .zgroup)")
        );
    }
    let node_type = root.get("node_type");
    match node_type.str("\"array\" or \"group\"")? {
        "array" => match wanted {
            Some(w) => Err(root.problem(&format!(
                "array {w:?} was requested but this is a single Zarr array; remove [input] array"
            ))),
            None => array(dir, &root),
        },
        "group" => {
            let ms = root.get("attributes").get("ome").get("multiscales");
            group(dir, &root, &ms, wanted, depth)
        }
        _ => Err(node_type.err("\"array\" or \"group\"")),
    }
}

/// A Zarr v2 node: `root` is its `.zarray` or `.zgroup`.
fn node_v2(
    dir: &Path,
    root: &J,
    wanted: Option<&str>,
    depth: usize,
) -> Result<ArrayMeta, VolumeError> {
    let format = root.get("zarr_format");
    if format.value.as_u64() != Some(2) {
        return Err(format.err("2 (a Zarr v2 .zarray or .zgroup)"));
    }
    if root.file.ends_with(".zarray") {
        return match wanted {
            Some(w) => Err(root.problem(&format!(
                "array {w:?} was requested but this is a single Zarr array; remove [input] array"
            ))),
            None => array_v2(dir, root),
        };
    }
    // A group's attributes (OME-Zarr v0.4's multiscales among them) live in .zattrs, which a
    // group without attributes may lack.
    let attrs_file = dir.join(".zattrs");
    let attrs_doc = if attrs_file.is_file() {
        read_json(&attrs_file)?
    } else {
        Value::Null
    };
    let attrs = J::root(&attrs_file, &attrs_doc);
    let said_by = if attrs.is_null() { root } else { &attrs };
    group(dir, said_by, &attrs.get("multiscales"), wanted, depth)
}

fn read_json(file: &Path) -> Result<Value, VolumeError> {
    let bytes = std::fs::read(file).map_err(|e| VolumeError::io(file, "read", e))?;
    serde_json::from_slice(&bytes).map_err(|e| {
        VolumeError::format(
            file,
            format!("line {} column {}", e.line(), e.column()),
            "valid JSON",
            e.to_string(),
        )
    })
}

/// A group: its OME-Zarr `multiscales` (`ms`: v0.5's `attributes.ome.multiscales`, v0.4's
/// `multiscales` in `.zattrs`; null when it has none) pick the level, else `wanted` names the
/// child. `root` is the metadata file errors about the group name.
fn group(
    dir: &Path,
    root: &J,
    ms: &J,
    wanted: Option<&str>,
    depth: usize,
) -> Result<ArrayMeta, VolumeError> {
    if ms.is_null() {
        return match wanted {
            Some(w) => node(&dir.join(w), None, depth + 1),
            None => Err(root.problem(&format!(
                "a Zarr group without OME-Zarr multiscales; set [input] array to one of its arrays [{}]",
                children(dir).join(", ")
            ))),
        };
    }
    let multiscales = ms.items("a list of multiscales")?;
    let m = multiscales
        .first()
        .ok_or_else(|| ms.err("at least one multiscale"))?;
    let list = m.get("datasets");
    let datasets = list.items("a list of datasets")?;
    let paths = datasets
        .iter()
        .map(|d| d.get("path").str("a dataset path"))
        .collect::<Result<Vec<_>, _>>()?;
    let pick = match wanted {
        None => 0,
        Some(w) => paths.iter().position(|p| *p == w).ok_or_else(|| {
            root.problem(&format!(
                "[input] array {w:?} is not a level of this OME-Zarr image; levels are [{}]",
                paths.join(", ")
            ))
        })?,
    };
    let dataset = datasets
        .get(pick)
        .ok_or_else(|| list.err("at least one dataset"))?;
    // A path of "" or "." names this group again, which would name its dataset again, forever.
    if Path::new(paths[pick])
        .components()
        .all(|c| c == std::path::Component::CurDir)
    {
        return Err(dataset.get("path").problem(&format!(
            "dataset path {:?} names this group itself; it must name one of its arrays (such as \"0\")",
            paths[pick]
        )));
    }
    let mut meta = node(&dir.join(paths[pick]), None, depth + 1)?;
    let rank = meta.shape.len();
    check_axes(&m.get("axes"), rank)?;
    // Dataset transformations first, then the multiscale's own (OME-Zarr v0.4 and v0.5).
    let (s1, t1) = transforms(&dataset.get("coordinateTransformations"), rank)?;
    let (s2, t2) = transforms(&m.get("coordinateTransformations"), rank)?;
    let scale: Vec<f64> = s1.iter().zip(&s2).map(|(a, b)| a * b).collect();
    let shift: Vec<f64> = (0..rank).map(|a| s2[a] * t1[a] + t2[a]).collect();
    // Zarr axes are (..., z, y, x); the grid wants x, y, z.
    let xyz = |v: &[f64]| [v[rank - 1], v[rank - 2], v[rank - 3]];
    meta.spacing = Some(xyz(&scale));
    meta.origin = Some(xyz(&shift));
    Ok(meta)
}

/// Refuses an OME-Zarr image whose last three axes are not the spatial z, y, x, in that order.
///
/// The reader takes the last three axes as z, y, x (x fastest) and streams z slices; a time or
/// channel axis there was meshed as depth with the time step as spacing, and axes listed as
/// x, y, z had x and z swapped with their spacing and origin. Mapping the names instead would
/// mean slicing along the fastest axis (every chunk of the volume decoded for each slice, or the
/// volume held whole) and mirrored meshes, so the store must be written in z, y, x order. An
/// axis is spatial when its `type` is `"space"`, or when it has no type and is named x, y or z
/// (OME-Zarr v0.3 lists bare names). Without `axes` the last three are taken as z, y, x.
fn check_axes(axes: &J, rank: usize) -> Result<(), VolumeError> {
    if axes.is_null() {
        return Ok(());
    }
    let items = axes.items("a list of axes")?;
    if items.len() != rank {
        return Err(axes.err(format!("{rank} axes, one per axis of the array")));
    }
    let mut named = Vec::with_capacity(rank);
    for a in &items {
        let (name, kind) = match a.value.as_str() {
            Some(n) => (n, None),
            None => (
                a.get("name").str("an axis name")?,
                a.get("type").value.as_str(),
            ),
        };
        named.push((name, kind));
    }
    let last = &named[rank - 3..];
    let listed = last
        .iter()
        .map(|(n, k)| match k {
            Some(k) => format!("{n} ({k})"),
            None => n.to_string(),
        })
        .collect::<Vec<_>>()
        .join(", ");
    let xyz = |n: &str| {
        ["x", "y", "z"]
            .iter()
            .position(|a| n.eq_ignore_ascii_case(a))
    };
    if let Some((n, k)) = last.iter().find(|(n, k)| match k {
        Some(k) => *k != "space",
        None => xyz(n).is_none(),
    }) {
        let what = k.map_or("not named x, y or z".to_string(), |k| {
            format!("of type {k}")
        });
        return Err(axes.problem(&format!(
            "the last three axes [{listed}] must be spatial (z, y, x) but {n} is {what}; write one 3-D volume (one time point, one channel) as its own image with axes z, y, x"
        )));
    }
    // Spatial axes of other names (a custom "depth") cannot be checked for order.
    let order: Option<Vec<usize>> = last.iter().map(|(n, _)| xyz(n)).collect();
    if let Some(order) = order
        && order != [2, 1, 0]
    {
        let from: Option<Vec<String>> = [2, 1, 0]
            .iter()
            .map(|want| Some(order.iter().position(|o| o == want)?.to_string()))
            .collect();
        let fix = match from {
            Some(from) => format!(
                "rewrite the array with its last three axes transposed to z, y, x (numpy: a.transpose({}) of those axes)",
                from.join(", ")
            ),
            None => "name them z, y, x, once each".to_string(),
        };
        return Err(axes.problem(&format!(
            "axes [{listed}]: only the order z, y, x (x varying fastest) is read, since the volume is streamed in z slices; {fix}"
        )));
    }
    Ok(())
}

/// Names of the sub-directories of a group that are Zarr nodes (v3 or v2), for error messages.
fn children(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter(|e| {
            let p = e.path();
            ["zarr.json", ".zarray", ".zgroup"]
                .iter()
                .any(|f| p.join(f).is_file())
        })
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Scale and translation of an OME-Zarr `coordinateTransformations` list (identity when absent).
fn transforms(j: &J, rank: usize) -> Result<(Vec<f64>, Vec<f64>), VolumeError> {
    let mut scale = vec![1.0; rank];
    let mut shift = vec![0.0; rank];
    if j.is_null() {
        return Ok((scale, shift));
    }
    for t in j.items("a list of transformations")? {
        let kind = t.get("type");
        let values = |key: &str, positive: bool| {
            let v = t.get(key);
            let what = if positive {
                "positive numbers"
            } else {
                "numbers"
            };
            let expected = format!("{rank} {what}, one per axis");
            let nums = v.f64s(&expected)?;
            if nums.len() != rank || (positive && nums.iter().any(|&x| x <= 0.0)) {
                return Err(v.err(expected));
            }
            Ok(nums)
        };
        match kind.str("\"scale\", \"translation\" or \"identity\"")? {
            "scale" => {
                let s = values("scale", true)?;
                for a in 0..rank {
                    scale[a] *= s[a];
                    shift[a] *= s[a];
                }
            }
            "translation" => {
                let t = values("translation", false)?;
                for a in 0..rank {
                    shift[a] += t[a];
                }
            }
            "identity" => {}
            _ => return Err(kind.err("\"scale\", \"translation\" or \"identity\"")),
        }
    }
    Ok((scale, shift))
}

/// The array's `shape`, checked: at least three axes, and any before the last three of size 1.
fn shape(root: &J) -> Result<Vec<u64>, VolumeError> {
    let shape_j = root.get("shape");
    let shape = shape_j.u64s("a list of sizes")?;
    let rank = shape.len();
    if rank < 3 {
        return Err(shape_j.err("at least 3 axes (z, y, x)"));
    }
    // Leading axes (OME-Zarr's t, c) are dropped when they hold one element; more would be
    // several volumes, and which one to mesh is not ours to guess.
    if let Some(a) = (0..rank - 3).find(|&a| shape[a] != 1) {
        let names = root.get("dimension_names");
        let label = names
            .value
            .get(a)
            .and_then(Value::as_str)
            .map(|n| format!(" ({n})"))
            .unwrap_or_default();
        return Err(shape_j.problem(&format!(
            "shape {shape:?}: axis {a}{label} has size {} but only the last three axes (z, y, x) may exceed 1; write the volume to mesh as its own array",
            shape[a]
        )));
    }
    Ok(shape)
}

/// A `chunks` (v2) or `chunk_shape` (v3) list: one positive size per axis.
fn chunk_shape(j: &J, rank: usize) -> Result<Vec<u64>, VolumeError> {
    let chunk_shape = j.u64s("a list of chunk sizes")?;
    if chunk_shape.len() != rank || chunk_shape.contains(&0) {
        return Err(j.err(format!("{rank} positive chunk sizes, one per axis")));
    }
    Ok(chunk_shape)
}

fn array(dir: &Path, root: &J) -> Result<ArrayMeta, VolumeError> {
    let shape = shape(root)?;
    let rank = shape.len();
    let ztype = ZType::parse(&root.get("data_type"))?;
    let grid = root.get("chunk_grid");
    let grid_name = grid.get("name");
    if grid_name.value.as_str() != Some("regular") {
        return Err(grid_name.err("\"regular\""));
    }
    let chunk_shape = chunk_shape(&grid.get("configuration").get("chunk_shape"), rank)?;
    let keys = key_encoding(&root.get("chunk_key_encoding"))?;
    let (fill, fill_saturated) = ztype.fill_value(&root.get("fill_value"))?;
    let codecs = codec::parse(&root.get("codecs"), &chunk_shape, ztype.size())?;
    let st = root.get("storage_transformers");
    if st.value.as_array().is_some_and(|a| !a.is_empty()) {
        return Err(st.problem("storage transformers are unsupported"));
    }
    Ok(ArrayMeta {
        dir: dir.to_path_buf(),
        shape,
        chunk_shape,
        ztype,
        fill,
        fill_saturated,
        keys,
        codecs,
        spacing: None,
        origin: None,
    })
}

/// A Zarr v2 array (`.zarray`): numpy dtype string, `order`, `compressor` (no `filters`),
/// `dimension_separator`, and chunk keys `i.j.k` or `i/j/k`.
fn array_v2(dir: &Path, root: &J) -> Result<ArrayMeta, VolumeError> {
    let shape = shape(root)?;
    let rank = shape.len();
    let (ztype, endian) = ZType::parse_v2(&root.get("dtype"))?;
    let chunk_shape = chunk_shape(&root.get("chunks"), rank)?;
    let order = root.get("order");
    let fortran = match order.value.as_str() {
        Some("C") => false,
        Some("F") => true,
        _ => return Err(order.err("\"C\" or \"F\"")),
    };
    let filters = root.get("filters");
    if !filters.is_null() && filters.value.as_array().is_none_or(|f| !f.is_empty()) {
        let ids = match filters.value.as_array() {
            Some(list) => list
                .iter()
                .map(|f| f.get("id").and_then(Value::as_str).unwrap_or("?"))
                .collect::<Vec<_>>()
                .join(", "),
            None => filters.value.to_string(),
        };
        return Err(filters.problem(&format!(
            "filters [{ids}] unsupported: write the array without filters (a compressor alone)"
        )));
    }
    let sep = root.get("dimension_separator");
    let separator = match sep.value.as_str() {
        None | Some(".") => '.',
        Some("/") => '/',
        Some(_) => return Err(sep.err("\".\" or \"/\"")),
    };
    // A null fill value leaves unwritten chunks undefined in Zarr v2 (zarr-python hands back
    // whatever its new buffer held, zeros in practice); read as 0 (docs/zarr.md says so).
    let fill_j = root.get("fill_value");
    let (fill, fill_saturated) = if fill_j.is_null() {
        (0.0, false)
    } else {
        ztype.fill_value(&fill_j)?
    };
    let codecs = codec::v2(
        &root.get("compressor"),
        endian,
        fortran,
        &chunk_shape,
        ztype.size(),
    )?;
    Ok(ArrayMeta {
        dir: dir.to_path_buf(),
        shape,
        chunk_shape,
        ztype,
        fill,
        fill_saturated,
        keys: KeyEncoding {
            v2: true,
            separator,
        },
        codecs,
        spacing: None,
        origin: None,
    })
}

fn key_encoding(j: &J) -> Result<KeyEncoding, VolumeError> {
    let name = j.get("name");
    let v2 = match name.str("\"default\" or \"v2\"")? {
        "default" => false,
        "v2" => true,
        _ => return Err(name.err("\"default\" or \"v2\"")),
    };
    let sep = j.get("configuration").get("separator");
    let separator = match sep.value.as_str() {
        None if v2 => '.',
        None => '/',
        Some("/") => '/',
        Some(".") => '.',
        Some(_) => return Err(sep.err("\"/\" or \".\"")),
    };
    Ok(KeyEncoding { v2, separator })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunk_keys_of_both_encodings() {
        let k = |v2, separator| KeyEncoding { v2, separator }.key(&[0, 2, 10]);
        assert_eq!(k(false, '/'), "c/0/2/10");
        assert_eq!(k(false, '.'), "c.0.2.10");
        assert_eq!(k(true, '.'), "0.2.10");
        assert_eq!(k(true, '/'), "0/2/10");
    }

    /// The `axes` of an OME-Zarr multiscale, checked as `group` does.
    fn axes(list: Value, rank: usize) -> Result<(), String> {
        let doc = serde_json::json!({ "axes": list });
        let file = Path::new("img.zarr/zarr.json");
        check_axes(&J::root(file, &doc).get("axes"), rank).map_err(|e| e.to_string())
    }

    #[test]
    fn spatial_axes_in_z_y_x_order_are_read() {
        let space = |n: &str| serde_json::json!({"name": n, "type": "space", "unit": "micrometer"});
        let zyx = serde_json::json!([
            {"name": "t", "type": "time"},
            {"name": "c", "type": "channel"},
            space("z"),
            space("y"),
            space("x")
        ]);
        assert_eq!(axes(zyx, 5), Ok(()));
        // v0.3's bare names, untyped names, and spatial axes of other names.
        assert_eq!(axes(serde_json::json!(["z", "y", "x"]), 3), Ok(()));
        assert_eq!(
            axes(
                serde_json::json!([{"name": "Z"}, {"name": "y"}, {"name": "x"}]),
                3
            ),
            Ok(())
        );
        let custom = serde_json::json!([space("depth"), space("row"), space("col")]);
        assert_eq!(axes(custom, 3), Ok(()));
        assert_eq!(axes(Value::Null, 3), Ok(()));
    }

    /// A time series or channels of 2-D images were meshed as a volume (time as depth).
    #[test]
    fn time_or_channel_among_the_last_three_axes_is_refused() {
        let space = |n: &str| serde_json::json!({"name": n, "type": "space"});
        let tyx = serde_json::json!([{"name": "t", "type": "time", "unit": "second"}, space("y"), space("x")]);
        assert_eq!(
            axes(tyx, 3).unwrap_err(),
            "img.zarr/zarr.json: key axes: the last three axes [t (time), y (space), x (space)] must be spatial (z, y, x) but t is of type time; write one 3-D volume (one time point, one channel) as its own image with axes z, y, x"
        );
        let cyx = serde_json::json!([{"name": "c", "type": "channel"}, space("y"), space("x")]);
        assert!(
            axes(cyx, 3)
                .unwrap_err()
                .contains("but c is of type channel;")
        );
        let untyped = serde_json::json!(["c", "y", "x"]);
        assert!(
            axes(untyped, 3)
                .unwrap_err()
                .contains("but c is not named x, y or z;")
        );
        let short = serde_json::json!([space("y"), space("x")]);
        assert!(
            axes(short, 3)
                .unwrap_err()
                .contains("expected 3 axes, one per axis of the array")
        );
    }

    /// Axes listed x, y, z (allowed by the spec) had x and z swapped silently.
    #[test]
    fn spatial_axes_in_another_order_are_refused() {
        let space = |n: &str| serde_json::json!({"name": n, "type": "space"});
        let xyz = serde_json::json!([space("x"), space("y"), space("z")]);
        assert_eq!(
            axes(xyz, 3).unwrap_err(),
            "img.zarr/zarr.json: key axes: axes [x (space), y (space), z (space)]: only the order z, y, x (x varying fastest) is read, since the volume is streamed in z slices; rewrite the array with its last three axes transposed to z, y, x (numpy: a.transpose(2, 1, 0) of those axes)"
        );
        let zxy = serde_json::json!(["z", "x", "y"]);
        assert!(axes(zxy, 3).unwrap_err().contains("a.transpose(0, 2, 1)"));
        let twice = serde_json::json!(["z", "x", "x"]);
        assert!(
            axes(twice, 3)
                .unwrap_err()
                .ends_with("; name them z, y, x, once each")
        );
    }
}
