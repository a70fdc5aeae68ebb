//! Zarr `data_type`s and `fill_value`s. Zarr has 64-bit integers, which the crate's [`Dtype`]
//! (shared with the job file's raw `dtype` key) does not; they are converted here, the other types
//! go through the crate's one tested conversion.

use super::json::J;
use crate::dtype::{decode, saturated_f32};
use crate::{Dtype, Endian, VolumeError};

/// A Zarr v3 numeric data type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ZType {
    Plain(Dtype),
    I64,
    U64,
}

const NAMES: &str = "int8, uint8, int16, uint16, int32, uint32, int64, uint64, float32 or float64";

impl ZType {
    pub(crate) fn parse(j: &J) -> Result<ZType, VolumeError> {
        let name = j.str(NAMES)?;
        Ok(match name {
            "int8" => ZType::Plain(Dtype::I8),
            "uint8" => ZType::Plain(Dtype::U8),
            "int16" => ZType::Plain(Dtype::I16),
            "uint16" => ZType::Plain(Dtype::U16),
            "int32" => ZType::Plain(Dtype::I32),
            "uint32" => ZType::Plain(Dtype::U32),
            "int64" => ZType::I64,
            "uint64" => ZType::U64,
            "float32" => ZType::Plain(Dtype::F32),
            "float64" => ZType::Plain(Dtype::F64),
            _ => return Err(j.err(NAMES)),
        })
    }

    /// A Zarr v2 `dtype`: a numpy type string such as `"<u2"`, `">f4"` or `"|u1"` (byte order,
    /// kind, size), with the byte order the chunks are stored in.
    pub(crate) fn parse_v2(j: &J) -> Result<(ZType, Endian), VolumeError> {
        const TYPESTRS: &str = "a numpy type string of a number: <, > or | then i1..i8, u1..u8, f4 or f8 (such as \"<u2\")";
        let s = j.str(TYPESTRS)?;
        let (endian, kind) = match s.split_at_checked(1) {
            Some(("<", k)) => (Endian::Little, k),
            Some((">", k)) => (Endian::Big, k),
            // "|": byte order does not apply, which numpy says only of 1-byte types.
            Some(("|", k @ ("i1" | "u1"))) => (Endian::Little, k),
            _ => return Err(j.err(TYPESTRS)),
        };
        let t = match kind {
            "i1" => ZType::Plain(Dtype::I8),
            "u1" => ZType::Plain(Dtype::U8),
            "i2" => ZType::Plain(Dtype::I16),
            "u2" => ZType::Plain(Dtype::U16),
            "i4" => ZType::Plain(Dtype::I32),
            "u4" => ZType::Plain(Dtype::U32),
            "i8" => ZType::I64,
            "u8" => ZType::U64,
            "f4" => ZType::Plain(Dtype::F32),
            "f8" => ZType::Plain(Dtype::F64),
            _ => return Err(j.err(TYPESTRS)),
        };
        Ok((t, endian))
    }

    pub(crate) fn size(self) -> usize {
        match self {
            ZType::Plain(d) => d.size_bytes(),
            ZType::I64 | ZType::U64 => 8,
        }
    }

    /// The crate's name for the stored type; none for 64-bit integers.
    pub(crate) fn dtype(self) -> Option<Dtype> {
        match self {
            ZType::Plain(d) => Some(d),
            ZType::I64 | ZType::U64 => None,
        }
    }

    /// Converts `out.len()` stored values to f32 (64-bit integers round to the nearest f32),
    /// and returns how many were saturated (finite f64 values beyond f32's range).
    pub(crate) fn decode(self, endian: Endian, bytes: &[u8], out: &mut [f32]) -> u64 {
        let wide = |b: &[u8]| {
            let a: [u8; 8] = b.try_into().unwrap_or_default();
            match endian {
                Endian::Little => u64::from_le_bytes(a),
                Endian::Big => u64::from_be_bytes(a),
            }
        };
        match self {
            ZType::Plain(d) => return decode(d, endian, bytes, out),
            ZType::I64 => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(8)) {
                    *o = wide(b) as i64 as f32;
                }
            }
            ZType::U64 => {
                for (o, b) in out.iter_mut().zip(bytes.chunks_exact(8)) {
                    *o = wide(b) as f32;
                }
            }
        }
        0
    }

    /// The values an integer type holds (`None` for floats). A fill value outside them is no
    /// value of the array: the input's range by its type, which an iso is checked against
    /// before any work, would not hold the fill voxels (a uint8 store filled with 300 had its
    /// iso 280 refused though those voxels cross it).
    fn integer_bounds(self) -> Option<(i128, i128)> {
        let (bytes, signed) = match self {
            ZType::Plain(Dtype::F32 | Dtype::F64) => return None,
            ZType::Plain(d) => (d.size_bytes(), d.name().starts_with('i')),
            ZType::I64 => (8, true),
            ZType::U64 => (8, false),
        };
        let bits = 8 * bytes as u32;
        Some(if signed {
            (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1)
        } else {
            (0, (1i128 << bits) - 1)
        })
    }

    /// The value of voxels in chunks that were never written: a number, or for floats "NaN",
    /// "Infinity", "-Infinity" or the bit pattern as "0x..." hex (Zarr v3 core spec); and
    /// whether it was saturated (a finite float64 beyond f32's range, as voxels are).
    pub(crate) fn fill_value(self, j: &J) -> Result<(f32, bool), VolumeError> {
        let float = matches!(self, ZType::Plain(Dtype::F32 | Dtype::F64));
        let expected = if float {
            "a number, \"NaN\", \"Infinity\", \"-Infinity\" or \"0x\" hex bits"
        } else {
            "an integer"
        };
        let integer =
            (j.value.as_i64().map(i128::from)).or_else(|| j.value.as_u64().map(i128::from));
        if let Some(v) = integer {
            if let Some((lo, hi)) = self.integer_bounds()
                && !(lo..=hi).contains(&v)
            {
                return Err(j.err(format!("an integer from {lo} to {hi} (the array's type)")));
            }
            return Ok((v as f32, false));
        }
        if !float {
            return Err(j.err(expected));
        }
        if let Some(v) = j.value.as_f64() {
            return Ok(saturated_f32(v));
        }
        let text = j.str(expected)?;
        let hex = |digits: &str| u64::from_str_radix(digits, 16).ok();
        let v = match (text, text.strip_prefix("0x")) {
            ("NaN", _) => Some((f32::NAN, false)),
            ("Infinity", _) => Some((f32::INFINITY, false)),
            ("-Infinity", _) => Some((f32::NEG_INFINITY, false)),
            (_, Some(d)) if self == ZType::Plain(Dtype::F32) && d.len() == 8 => {
                hex(d).map(|b| (f32::from_bits(b as u32), false))
            }
            (_, Some(d)) if d.len() == 16 => hex(d).map(|b| saturated_f32(f64::from_bits(b))),
            _ => None,
        };
        v.ok_or_else(|| j.err(expected))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn fill(ty: &str, json: &str) -> Result<f32, String> {
        let v: serde_json::Value =
            serde_json::from_str(&format!(r#"{{"t":"{ty}","f":{json}}}"#)).unwrap();
        let root = J::root(Path::new("zarr.json"), &v);
        let t = ZType::parse(&root.get("t")).map_err(|e| e.to_string())?;
        t.fill_value(&root.get("f"))
            .map(|(v, _)| v)
            .map_err(|e| e.to_string())
    }

    #[test]
    fn fill_values_of_every_form() {
        assert_eq!(fill("uint8", "7"), Ok(7.0));
        assert_eq!(fill("int64", "-3"), Ok(-3.0));
        assert_eq!(fill("float32", "0.5"), Ok(0.5));
        assert_eq!(fill("float32", "\"-Infinity\""), Ok(f32::NEG_INFINITY));
        assert!(fill("float64", "\"NaN\"").unwrap().is_nan());
        assert_eq!(fill("float32", "\"0x3f800000\""), Ok(1.0));
        assert_eq!(fill("float64", "\"0x4000000000000000\""), Ok(2.0));
        // Beyond f32's range: saturated like the voxels, not infinite.
        assert_eq!(fill("float64", "1e40"), Ok(f32::MAX));
        assert_eq!(fill("float64", "\"0xc800000000000000\""), Ok(-f32::MAX));
        assert_eq!(fill("uint64", "18446744073709551615"), Ok(u64::MAX as f32));
        assert_eq!(fill("int8", "-128"), Ok(-128.0));
        for (ty, bad) in [
            ("uint8", "300"),
            ("uint8", "-1"),
            ("int8", "128"),
            ("uint64", "-1"),
        ] {
            assert!(
                fill(ty, bad)
                    .unwrap_err()
                    .starts_with("zarr.json: key f: expected an integer from"),
                "{ty} {bad}"
            );
        }
        assert_eq!(
            fill("uint16", "70000").unwrap_err(),
            r#"zarr.json: key f: expected an integer from 0 to 65535 (the array's type), found "70000""#
        );
        assert_eq!(fill("float32", "300"), Ok(300.0));
        assert_eq!(
            fill("uint16", "\"NaN\"").unwrap_err(),
            r#"zarr.json: key f: expected an integer, found "NaN""#
        );
        assert_eq!(
            fill("bool", "0").unwrap_err(),
            format!(r#"zarr.json: key t: expected {NAMES}, found "bool""#)
        );
    }

    #[test]
    fn numpy_type_strings() {
        let parse = |t: &str| {
            let v = serde_json::json!({ "dtype": t });
            let root = J::root(Path::new(".zarray"), &v);
            ZType::parse_v2(&root.get("dtype")).map_err(|e| e.to_string())
        };
        assert_eq!(parse("<u2"), Ok((ZType::Plain(Dtype::U16), Endian::Little)));
        assert_eq!(parse(">f4"), Ok((ZType::Plain(Dtype::F32), Endian::Big)));
        assert_eq!(parse("|u1"), Ok((ZType::Plain(Dtype::U8), Endian::Little)));
        assert_eq!(parse(">i8"), Ok((ZType::I64, Endian::Big)));
        assert_eq!(parse("<f8"), Ok((ZType::Plain(Dtype::F64), Endian::Little)));
        for bad in ["|u2", "<b1", "<c8", "u2", "<f2", "<M8[ns]", ""] {
            assert!(
                parse(bad)
                    .unwrap_err()
                    .starts_with(".zarray: key dtype: expected a numpy type string"),
                "{bad}"
            );
        }
    }

    #[test]
    fn wide_integers_decode_in_both_orders() {
        let mut out = [0.0f32; 2];
        let mut bytes = (-5i64).to_be_bytes().to_vec();
        bytes.extend_from_slice(&(1u64 << 40).to_be_bytes());
        ZType::I64.decode(Endian::Big, &bytes, &mut out[..1]);
        ZType::U64.decode(Endian::Big, &bytes[8..], &mut out[1..]);
        assert_eq!(out, [-5.0, (1u64 << 40) as f32]);
    }
}
