//! Checks every volume of the shared data set (when present) against its `meta.json`: dims,
//! stored type, spacing where the metadata states one, and min / max / mean of the voxels. The
//! metadata was produced by VTK, pynrrd and nibabel, so this is an independent oracle for each
//! reader.

use crate::testutil::read_all;
use crate::{Dtype, OpenOptions, open_path};
use std::path::PathBuf;

const DATA: &str = "/work/shared/data";

/// The file our readers open in each folder (meta.json names the decoded raw copy instead).
const FILES: &[(&str, &str)] = &[
    ("aneurism", "aneurism.vti"),
    ("bonsai", "bonsai.vti"),
    ("cthead_8bit", "cthead_8bit_256x256x99_uint8.raw"),
    ("engine", "engine.vti"),
    ("engine", "engine_256x256x128_uint8.raw"),
    ("headsq", "quarter.nhdr"),
    ("hydrogen", "hydrogen.vti"),
    ("ironprot", "ironProt.vtk"),
    ("mean_head", "mean_reg2mean.nii.gz"),
    ("mni152", "mni_icbm152_t1_tal_nlin_sym_09a_converted.nii.gz"),
    ("silicium", "silicium_98x34x34_uint8.raw"),
    ("stent", "stent_128x128x256_int16.raw"),
    ("tooth", "tooth.nrrd"),
];

#[derive(serde::Deserialize)]
struct Meta {
    dims: [u64; 3],
    dtype: String,
    spacing: Option<[f64; 3]>,
    value_min: f64,
    value_max: f64,
    value_mean: f64,
}

fn dtype(meta: &str) -> Dtype {
    serde_json::from_value(serde_json::Value::String(
        meta.trim_end_matches("le").into(),
    ))
    .unwrap()
}

fn present() -> Option<PathBuf> {
    let dir = PathBuf::from(DATA);
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: {DATA} not present");
        None
    }
}

#[test]
fn every_shared_volume_matches_its_meta() {
    let Some(root) = present() else { return };
    for (folder, file) in FILES {
        let meta: Meta =
            serde_json::from_slice(&std::fs::read(root.join(folder).join("meta.json")).unwrap())
                .unwrap();
        let path = root.join(folder).join(file);
        // Raw files have no header: the job file would say what meta.json says.
        let opts = if file.ends_with(".raw") {
            OpenOptions {
                dims: Some(meta.dims),
                dtype: Some(dtype(&meta.dtype)),
                spacing: meta.spacing,
                ..Default::default()
            }
        } else {
            OpenOptions::default()
        };
        let v = open_path(&path, &opts).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(v.grid().dims, meta.dims, "{file}");
        assert_eq!(v.dtype(), Some(dtype(&meta.dtype)), "{file}");
        if let Some(s) = meta.spacing {
            let g = v.grid().spacing;
            assert!(
                g.iter().zip(s).all(|(a, b)| (a - b).abs() < 1e-6),
                "{file}: {g:?}"
            );
        }
        let all = read_all(&path, &opts).unwrap();
        let mean = all.iter().map(|&x| f64::from(x)).sum::<f64>() / all.len() as f64;
        let min = all.iter().fold(f32::MAX, |m, &x| m.min(x));
        let max = all.iter().fold(f32::MIN, |m, &x| m.max(x));
        assert_eq!(f64::from(min), meta.value_min, "{file} min");
        assert_eq!(f64::from(max), meta.value_max, "{file} max");
        assert!((mean - meta.value_mean).abs() < 1e-4, "{file} mean {mean}");
    }
}

#[test]
fn engine_vti_equals_engine_raw_voxel_for_voxel() {
    let Some(root) = present() else { return };
    let dir = root.join("engine");
    let raw = OpenOptions {
        dims: Some([256, 256, 128]),
        dtype: Some(Dtype::U8),
        ..Default::default()
    };
    let mut a = open_path(&dir.join("engine.vti"), &OpenOptions::default()).unwrap();
    let mut b = open_path(&dir.join("engine_256x256x128_uint8.raw"), &raw).unwrap();
    assert_eq!(a.grid(), b.grid());
    let (mut sa, mut sb) = (vec![0.0f32; 65536], vec![0.0f32; 65536]);
    for z in 0..128 {
        a.read_slice(z, &mut sa).unwrap();
        b.read_slice(z, &mut sb).unwrap();
        assert!(sa == sb, "slice {z} differs");
    }
}
