//! Vertex identity: the grid edge a vertex lies on, packed into a `u64`.

/// A grid edge from voxel (x, y, z) to the next voxel along `axis` (0 = x, 1 = y, 2 = z),
/// packed as `3 * (x + nx * (y + ny * z)) + axis`.
///
/// Every surface vertex lies on exactly one grid edge, so the key is the vertex's identity
/// across cubes, batches and stages without hashing coordinates. Keys sort in traversal order
/// (x fastest, then y, then z) and are 64-bit, so volumes beyond 2^31 voxels work.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Debug)]
pub struct EdgeKey(pub u64);

impl EdgeKey {
    /// The key of the edge from voxel (x, y, z) along `axis` in a grid of `dims` voxels.
    #[inline]
    pub fn new(x: u64, y: u64, z: u64, axis: u8, dims: [u64; 3]) -> Self {
        debug_assert!(axis < 3 && x < dims[0] && y < dims[1] && z < dims[2]);
        EdgeKey(3 * (x + dims[0] * (y + dims[1] * z)) + u64::from(axis))
    }

    /// The edge's start voxel and axis.
    pub fn decode(self, dims: [u64; 3]) -> ([u64; 3], u8) {
        let (voxel, axis) = (self.0 / 3, (self.0 % 3) as u8);
        let x = voxel % dims[0];
        let rest = voxel / dims[0];
        ([x, rest % dims[1], rest / dims[1]], axis)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn packs_in_traversal_order() {
        let dims = [4, 5, 6];
        assert_eq!(EdgeKey::new(0, 0, 0, 0, dims), EdgeKey(0));
        assert_eq!(EdgeKey::new(0, 0, 0, 2, dims), EdgeKey(2));
        assert_eq!(EdgeKey::new(1, 0, 0, 0, dims), EdgeKey(3));
        assert_eq!(EdgeKey::new(0, 1, 0, 1, dims), EdgeKey(3 * 4 + 1));
        assert_eq!(EdgeKey::new(0, 0, 1, 0, dims), EdgeKey(3 * 20));
        assert!(EdgeKey::new(3, 4, 0, 2, dims) < EdgeKey::new(0, 0, 1, 0, dims));
    }

    #[test]
    fn beyond_32_bits() {
        let dims = [100_000, 100_000, 100_000];
        let k = EdgeKey::new(99_999, 99_999, 99_999, 2, dims);
        assert!(k.0 > u64::from(u32::MAX));
        assert_eq!(k.decode(dims), ([99_999, 99_999, 99_999], 2));
    }

    proptest! {
        #[test]
        fn decode_inverts_new(
            dims in prop::array::uniform3(1u64..1000),
            f in prop::array::uniform3(0.0f64..1.0),
            axis in 0u8..3,
        ) {
            let v = [0, 1, 2].map(|i| (f[i] * dims[i] as f64) as u64);
            prop_assert_eq!(EdgeKey::new(v[0], v[1], v[2], axis, dims).decode(dims), (v, axis));
        }
    }
}
