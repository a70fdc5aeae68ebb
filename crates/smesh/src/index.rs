//! The triangle index encoding shared by SMA and SMB: a positive n is the 1-based absolute index
//! of a vertex that stays active; a negative n counts back from the latest vertex (-1) and marks
//! the vertex's last use. SMB stores 32-bit signed indices; SMA text can hold any i64.

use crate::StreamFault;

/// Encodes vertex `v` as seen by a triangle written after `available` vertices.
pub(crate) fn encode(v: u64, last_use: bool, available: u64) -> i64 {
    if last_use {
        v as i64 - available as i64
    } else {
        v as i64 + 1
    }
}

/// Decodes a stored index into (0-based absolute index, finalizes) given `available` vertices.
/// Index 0 has no meaning and is reported by the caller as a syntax error (`None`).
pub(crate) fn decode(n: i64, available: u64) -> Option<Result<(u64, bool), StreamFault>> {
    match n {
        0 => None,
        n if n > 0 => Some(Ok((n as u64 - 1, false))),
        n if n.unsigned_abs() <= available => Some(Ok((available - n.unsigned_abs(), true))),
        index => Some(Err(StreamFault::BeforeFirst { index, available })),
    }
}

/// The largest SMB vertex count whose indices all fit an i32 (absolute 1-based and relative).
pub(crate) const MAX_VERTICES: u64 = i32::MAX as u64;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        for (v, last, avail) in [(0, false, 1), (0, true, 1), (5, true, 9), (8, false, 9)] {
            let n = encode(v, last, avail);
            assert_eq!(decode(n, avail), Some(Ok((v, last))));
        }
        assert_eq!(encode(8, true, 9), -1);
        assert_eq!(decode(0, 3), None);
        assert_eq!(
            decode(-4, 3),
            Some(Err(StreamFault::BeforeFirst {
                index: -4,
                available: 3
            }))
        );
    }
}
