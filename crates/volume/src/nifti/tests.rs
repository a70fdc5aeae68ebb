use super::*;
use crate::dtype::tests::{ALL, encode, sample_values};
use crate::open_path;
use crate::testutil::{assert_all_equal, gzip, outcome, read_all};

fn code(d: Dtype) -> i16 {
    match d {
        Dtype::U8 => 2,
        Dtype::I16 => 4,
        Dtype::I32 => 8,
        Dtype::F32 => 16,
        Dtype::F64 => 64,
        Dtype::I8 => 256,
        Dtype::U16 => 512,
        Dtype::U32 => 768,
    }
}

/// A NIfTI-1 header for a 3x2x4 volume; `edit` may change fields before encoding.
struct Hdr {
    endian: Endian,
    dim: [i16; 8],
    datatype: i16,
    pixdim: [f32; 8],
    vox_offset: f32,
    slope: f32,
    inter: f32,
    /// srow_x, srow_y, srow_z (sform_code 1 when set).
    sform: Option<[[f32; 4]; 3]>,
    /// quatern_b, c, d and qoffset x, y, z (qform_code 1 when set).
    qform: Option<([f32; 3], [f32; 3])>,
    magic: &'static [u8; 4],
    sizeof_hdr: i32,
}

impl Hdr {
    fn new(d: Dtype, endian: Endian) -> Self {
        Hdr {
            endian,
            dim: [3, 3, 2, 4, 1, 1, 1, 1],
            datatype: code(d),
            pixdim: [1.0, 0.5, 2.0, 1.5, 1.0, 0.0, 0.0, 0.0],
            vox_offset: 352.0,
            slope: 0.0,
            inter: 0.0,
            sform: None,
            qform: None,
            magic: b"n+1\0",
            sizeof_hdr: 348,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        let mut b = vec![0u8; 352];
        let big = self.endian == Endian::Big;
        let mut put = |o: usize, v: &[u8]| b[o..o + v.len()].copy_from_slice(v);
        macro_rules! enc {
            ($v:expr) => {
                if big {
                    $v.to_be_bytes()
                } else {
                    $v.to_le_bytes()
                }
            };
        }
        put(0, &enc!(self.sizeof_hdr));
        for (k, d) in self.dim.iter().enumerate() {
            put(40 + 2 * k, &enc!(*d));
        }
        put(70, &enc!(self.datatype));
        for (k, p) in self.pixdim.iter().enumerate() {
            put(76 + 4 * k, &enc!(*p));
        }
        put(108, &enc!(self.vox_offset));
        put(112, &enc!(self.slope));
        put(116, &enc!(self.inter));
        if let Some(rows) = self.sform {
            put(254, &enc!(1i16));
            for (r, row) in rows.iter().enumerate() {
                for (c, v) in row.iter().enumerate() {
                    put(280 + 16 * r + 4 * c, &enc!(*v));
                }
            }
        }
        if let Some((quatern, offset)) = self.qform {
            put(252, &enc!(1i16));
            for (k, v) in quatern.iter().chain(&offset).enumerate() {
                put(256 + 4 * k, &enc!(*v));
            }
        }
        put(344, self.magic);
        b
    }
}

/// An sform with steps `diag` along the axes (negative: flipped) and translation `t`.
fn affine(diag: [f32; 3], t: [f32; 3]) -> [[f32; 4]; 3] {
    let mut rows = [[0.0; 4]; 3];
    for k in 0..3 {
        rows[k][k] = diag[k];
        rows[k][3] = t[k];
    }
    rows
}

/// The grid and dropped orientation of a 3x2x4 u8 `.nii` with header `h`.
fn placement(h: &Hdr) -> (Grid, Orientation) {
    let dir = tempfile::tempdir().unwrap();
    let mut file = h.bytes();
    file.extend([0u8; 24]);
    let p = dir.path().join("o.nii");
    std::fs::write(&p, &file).unwrap();
    let v = open_path(&p, &OpenOptions::default()).unwrap();
    (v.grid(), v.orientation())
}

/// sform_code > 0: spacing and origin both from the sform (a tool that rewrote only the sform
/// left pixdim at 1), flips reported; else the qform with pixdim.
#[test]
fn sform_then_qform_place_the_grid() {
    let mut h = Hdr::new(Dtype::U8, Endian::Little);
    h.pixdim = [1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0];
    h.sform = Some(affine([0.5, 0.8, 1.2], [10.0, -5.0, 3.0]));
    let (g, o) = placement(&h);
    let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-6);
    assert!(close(g.spacing, [0.5, 0.8, 1.2]), "{:?}", g.spacing);
    assert_eq!((g.origin, o), ([10.0, -5.0, 3.0], Orientation::Aligned));
    // LAS: x steps backwards from the origin.
    h.sform = Some(affine([-0.5, 0.8, 1.2], [10.0, -5.0, 3.0]));
    let (g, o) = placement(&h);
    assert!(close(g.spacing, [0.5, 0.8, 1.2]), "{:?}", g.spacing);
    assert_eq!(o, Orientation::Flipped([true, false, false]));
    // A rotation of the sform about z.
    let mut rot = affine([0.0, 0.0, 1.0], [0.0; 3]);
    rot[0][1] = -1.0;
    rot[1][0] = 1.0;
    h.sform = Some(rot);
    assert_eq!(placement(&h).1, Orientation::Rotated);
    // qform only: pixdim and qoffset; quaternion (0, 1, 0) turns x and z about y, and qfac -1
    // turns z back: only x is flipped.
    h.sform = None;
    h.pixdim = [-1.0, 0.5, 2.0, 1.5, 1.0, 0.0, 0.0, 0.0];
    h.qform = Some(([0.0, 1.0, 0.0], [4.0, 5.0, 6.0]));
    let (g, o) = placement(&h);
    assert_eq!((g.spacing, g.origin), ([0.5, 2.0, 1.5], [4.0, 5.0, 6.0]));
    assert_eq!(o, Orientation::Flipped([true, false, false]));
    h.qform = Some(([0.0, 0.0, 0.0], [4.0, 5.0, 6.0]));
    h.pixdim[0] = 1.0;
    assert_eq!(placement(&h).1, Orientation::Aligned);
}

#[test]
fn every_type_endian_and_compression() {
    let dir = tempfile::tempdir().unwrap();
    for d in ALL {
        for e in [Endian::Little, Endian::Big] {
            let values = sample_values(d, 24);
            let mut file = Hdr::new(d, e).bytes();
            file.extend(encode(d, e, &values));
            let want: Vec<f32> = values.iter().map(|&x| x as f32).collect();
            for (name, bytes) in [("v.nii", file.clone()), ("v.nii.gz", gzip(&file))] {
                let p = dir.path().join(name);
                std::fs::write(&p, bytes).unwrap();
                assert_eq!(
                    read_all(&p, &OpenOptions::default()).unwrap(),
                    want,
                    "{d} {e:?} {name}"
                );
                let v = open_path(&p, &OpenOptions::default()).unwrap();
                assert_eq!(v.grid().spacing, [0.5, 2.0, 1.5]);
                assert_eq!(v.dtype(), Some(d));
            }
        }
    }
}

/// Finite doubles beyond f32's range read as ±f32::MAX and are counted, mapped or gzipped,
/// with and without a scaling (which keeps them within f32: scl_inter 1).
#[test]
fn doubles_beyond_f32_are_saturated_and_counted() {
    let dir = tempfile::tempdir().unwrap();
    let (values, want, n) = crate::testutil::beyond_f32();
    for e in [Endian::Little, Endian::Big] {
        for (slope, inter) in [(0.0, 0.0), (1.0, 1.0)] {
            let mut h = Hdr::new(Dtype::F64, e);
            (h.slope, h.inter) = (slope, inter);
            let mut file = h.bytes();
            file.extend(encode(Dtype::F64, e, &values));
            let want: Vec<f32> = want.iter().map(|v| v + inter).collect();
            for (name, bytes) in [("v.nii", file.clone()), ("v.nii.gz", gzip(&file))] {
                let p = dir.path().join(name);
                std::fs::write(&p, bytes).unwrap();
                let (got, saturated) =
                    crate::testutil::read_all_saturated(&p, &OpenOptions::default()).unwrap();
                assert!(
                    crate::testutil::same_values(&got, &want),
                    "{e:?} {name} {slope}: {got:?}"
                );
                assert_eq!(saturated, n, "{e:?} {name} {slope}");
            }
        }
    }
}

/// Doubles beyond f32's range are scaled in f64 before they are narrowed: a stored 1e39 with
/// scl_slope 1e-3 is 1e36 (saturating first made it 3.4e35), and only a scaled value still
/// beyond f32 is saturated and counted; mapped or gzipped, either byte order. A stored value
/// within f32 that the scaling takes beyond it is refused, as for every type.
#[test]
fn doubles_are_scaled_before_they_are_saturated() {
    let dir = tempfile::tempdir().unwrap();
    let mut values: Vec<f64> = (0..24).map(|i| f64::from(i) * 1000.0).collect();
    values[1] = 1e39;
    values[4] = -2e39;
    values[9] = 1e44; // 1e41 scaled: still beyond f32
    values[10] = -f64::MAX;
    values[20] = f64::INFINITY;
    values[22] = f64::NAN;
    let (slope, inter) = (1e-3f32, 2.0f32);
    let want: Vec<f32> = values
        .iter()
        .map(|&v| {
            let scaled = v * f64::from(slope) + f64::from(inter);
            match scaled {
                s if s.is_finite() && s.abs() > f64::from(f32::MAX) => f32::MAX.copysign(s as f32),
                s => s as f32,
            }
        })
        .collect();
    assert!(want[1] > 9.9e35 && want[1] < 1.01e36, "{}", want[1]);
    for e in [Endian::Little, Endian::Big] {
        let mut h = Hdr::new(Dtype::F64, e);
        (h.slope, h.inter) = (slope, inter);
        let mut file = h.bytes();
        file.extend(encode(Dtype::F64, e, &values));
        for (name, bytes) in [("d.nii", file.clone()), ("d.nii.gz", gzip(&file))] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            let (got, saturated) =
                crate::testutil::read_all_saturated(&p, &OpenOptions::default()).unwrap();
            assert!(
                crate::testutil::same_values(&got, &want),
                "{e:?} {name}: {got:?} against {want:?}"
            );
            assert_eq!(saturated, 2, "{e:?} {name}");
        }
    }
    // 1e36 is within f32; times 1e3 it is not: the header's scaling is refused.
    let mut h = Hdr::new(Dtype::F64, Endian::Little);
    h.slope = 1e3;
    values[1] = 1e36;
    let mut file = h.bytes();
    file.extend(encode(Dtype::F64, Endian::Little, &values));
    let p = dir.path().join("o.nii");
    std::fs::write(&p, &file).unwrap();
    let err = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("o.nii: header field scl_slope: expected a scaling that keeps every voxel")
            && err.contains(
                "the stored value 1000000000000000000000000000000000000 of slice 0 becomes infinite"
            )
            && !err.contains('\n'),
        "{err}"
    );
}

/// A scl_slope that overflows f32 on stored values made them infinite, meshed as outside with
/// exit 0: refused, naming the field.
#[test]
fn scaling_past_f32_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = Hdr::new(Dtype::F32, Endian::Little);
    h.slope = 1e38;
    let values: Vec<f64> = (0..24).map(|i| i as f64 * 0.25).collect();
    let mut file = h.bytes();
    file.extend(encode(Dtype::F32, Endian::Little, &values));
    let p = dir.path().join("s.nii");
    std::fs::write(&p, &file).unwrap();
    let err = read_all(&p, &OpenOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("s.nii: header field scl_slope: expected a scaling that keeps every voxel")
            && err.contains("the stored value 3.5 of slice 2 becomes infinite")
            && err.ends_with("found \"1e38\""),
        "{err}"
    );
    // Stored infinities stay what they are: the scaling did not make them.
    h.slope = 2.0;
    let mut file = h.bytes();
    let mut values = values;
    values[3] = f64::INFINITY;
    file.extend(encode(Dtype::F32, Endian::Little, &values));
    std::fs::write(&p, &file).unwrap();
    let read = read_all(&p, &OpenOptions::default()).unwrap();
    assert!(read[3].is_infinite() && read[4] == 2.0, "{read:?}");
}

#[test]
fn scaling_origin_and_pairs() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = Hdr::new(Dtype::I16, Endian::Little);
    h.slope = 0.5;
    h.inter = -10.0;
    h.sform = Some(affine([0.5, 2.0, 1.5], [-90.0, 126.0, -72.0]));
    let values: Vec<f64> = (0..24).map(|i| i as f64 * 4.0).collect();
    let mut file = h.bytes();
    file.extend(encode(Dtype::I16, Endian::Little, &values));
    let p = dir.path().join("s.nii");
    std::fs::write(&p, &file).unwrap();
    let want: Vec<f32> = values.iter().map(|&x| (x * 0.5 - 10.0) as f32).collect();
    assert_eq!(read_all(&p, &OpenOptions::default()).unwrap(), want);
    assert_eq!(
        open_path(&p, &OpenOptions::default())
            .unwrap()
            .grid()
            .origin,
        [-90.0, 126.0, -72.0]
    );
    // Pair: header in .hdr, voxels in .img from vox_offset 0.
    h.magic = b"ni1\0";
    h.vox_offset = 0.0;
    std::fs::write(dir.path().join("p.hdr"), &h.bytes()[..348]).unwrap();
    std::fs::write(
        dir.path().join("p.img"),
        encode(Dtype::I16, Endian::Little, &values),
    )
    .unwrap();
    assert_eq!(
        read_all(&dir.path().join("p.hdr"), &OpenOptions::default()).unwrap(),
        want
    );
    // nibabel's gzipped pair: both parts gzipped.
    std::fs::write(dir.path().join("g.hdr.gz"), gzip(&h.bytes()[..348])).unwrap();
    std::fs::write(
        dir.path().join("g.img.gz"),
        gzip(&encode(Dtype::I16, Endian::Little, &values)),
    )
    .unwrap();
    assert_eq!(
        read_all(&dir.path().join("g.hdr.gz"), &OpenOptions::default()).unwrap(),
        want
    );
}

#[test]
fn bad_files_give_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let data = encode(Dtype::U8, Endian::Little, &[1.0; 24]);
    let with = |edit: &dyn Fn(&mut Hdr)| {
        let mut h = Hdr::new(Dtype::U8, Endian::Little);
        edit(&mut h);
        let mut f = h.bytes();
        f.extend(&data);
        f
    };
    let good = with(&|_| {});
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "a.nii",
            good[..200].to_vec(),
            "header: expected a 348-byte NIfTI-1 header, found \"failed to fill whole buffer\"",
        ),
        (
            "a.nii",
            with(&|h| h.sizeof_hdr = 12),
            "header field sizeof_hdr: expected 348 (NIfTI-1), found \"12\"",
        ),
        (
            "a.nii",
            with(&|h| h.sizeof_hdr = 540),
            "header field sizeof_hdr: expected 348 (NIfTI-1; NIfTI-2 is not supported), found \"540\"",
        ),
        (
            "a.nii",
            with(&|h| h.magic = b"abc\0"),
            "header field magic: expected \"n+1\" or \"ni1\", found \"abc\\0\"",
        ),
        (
            "a.nii",
            with(&|h| h.dim = [4, 3, 2, 4, 5, 1, 1, 1]),
            "header field dim: expected a 3D volume (dim[0] >= 3 and dim[4..] = 1), found \"[4, 3, 2, 4, 5]\"",
        ),
        (
            "a.nii",
            with(&|h| h.datatype = 1024),
            "header field datatype: expected a scalar type code (2, 4, 8, 16, 64, 256, 512, 768), found \"1024\"",
        ),
        (
            "a.nii",
            with(&|h| h.vox_offset = 100.0),
            "header field vox_offset: expected a whole number of bytes >= 348, found \"100\"",
        ),
        (
            "a.nii",
            with(&|h| h.dim = [3, 3, 0, 4, 1, 1, 1, 1]),
            "dims 3x0x4 need at least 2 voxels per axis; check the dims",
        ),
        (
            "a.nii",
            with(&|h| h.dim = [3, 3, -2, 4, 1, 1, 1, 1]),
            "header field dim: expected positive sizes, found \"[3, -2, 4]\"",
        ),
        (
            "a.nii",
            with(&|h| h.pixdim[2] = 0.0),
            "the header's spacing [0.5, 0.0, 1.5] must be finite and > 0 on every axis; fix the header or set [input] spacing",
        ),
        (
            "a.nii",
            good[..370].to_vec(),
            "file is 370 bytes but dims 3x2x4 of u8 plus 352 header bytes need 376; check the NIfTI header's dim, datatype and vox_offset",
        ),
        (
            "a.nii.gz",
            gzip(&good[..370]),
            "gzip NIfTI voxels voxel 18 (slice 3): expected 24 voxels of u8 for dims 3x2x4, found \"end of data (truncated file?)\"",
        ),
        (
            "a.nii.gz",
            {
                let mut g = gzip(&good);
                let n = g.len();
                g[n - 20..n - 10].fill(0xAA);
                g
            },
            "header: expected a 348-byte NIfTI-1 header, found \"incomplete deflate stream\"",
        ),
    ];
    assert_all_equal(cases.into_iter().map(|(name, file, want)| {
        let p = dir.path().join(name);
        std::fs::write(&p, &file).unwrap();
        (outcome(&p), format!("{}: {want}", p.display()))
    }));
}

/// Valid small files for the robustness checks: `.nii` and `.nii.gz`.
pub(crate) fn samples() -> Vec<(&'static str, Vec<u8>)> {
    let mut nii = Hdr::new(Dtype::U16, Endian::Little).bytes();
    nii.extend(encode(
        Dtype::U16,
        Endian::Little,
        &sample_values(Dtype::U16, 24),
    ));
    let gz = gzip(&nii);
    vec![("sample.nii", nii), ("sample.nii.gz", gz)]
}
