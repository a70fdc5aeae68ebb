//! What a header says about the direction of the voxel axes that an axis-aligned [`crate::Grid`]
//! cannot hold. Readers keep the grid's positions `origin + spacing * (i, j, k)` (the header's
//! origin, the steps' lengths) and say what they left out through
//! [`crate::VolumeSource::orientation`]: axis flips, which the pipeline applies exactly where it
//! writes the mesh (a flipped axis's voxels lie at `origin - spacing * i`), and rotations, which
//! it warns about.

/// The part of a header's orientation that the grid dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Orientation {
    /// Every index axis steps along +x, +y, +z (or the format has no orientation): nothing
    /// was dropped.
    #[default]
    Aligned,
    /// Every index axis steps along its own physical axis, those marked `true` (x, y, z)
    /// backwards: the header's box on such an axis ends at its origin instead of starting
    /// there, and the mesh is mirrored.
    Flipped([bool; 3]),
    /// The index axes are rotated, permuted or sheared against the physical axes (with or
    /// without flips).
    Rotated,
}

/// Off-diagonal parts below this share of an axis' step length are rounding noise (headers
/// store directions in f32), not a rotation.
const TOLERANCE: f64 = 1e-6;

impl Orientation {
    /// The orientation of index axes whose steps are `columns` (axis k's step vector in
    /// physical x, y, z, any length). A zero or non-finite column (NRRD's `none`, a broken
    /// header) counts as aligned: its length is the spacing's problem, reported there.
    pub(crate) fn of_columns(columns: [[f64; 3]; 3]) -> Orientation {
        let mut flips = [false; 3];
        for (k, c) in columns.iter().enumerate() {
            let len = step_length(*c);
            if !(len.is_finite() && len > 0.0) {
                continue;
            }
            let off = (0..3)
                .filter(|&r| r != k)
                .map(|r| c[r].abs())
                .fold(0.0, f64::max);
            if off > TOLERANCE * len {
                return Orientation::Rotated;
            }
            flips[k] = c[k] < 0.0;
        }
        Orientation::from_flips(flips)
    }

    /// `Flipped` when any axis is, else `Aligned`.
    pub(crate) fn from_flips(flips: [bool; 3]) -> Orientation {
        if flips.contains(&true) {
            Orientation::Flipped(flips)
        } else {
            Orientation::Aligned
        }
    }

    /// One sentence for the run's warnings when the header rotates or permutes the axes, which
    /// no mesh is placed by: what was dropped and where the mesh is instead. `None` for aligned
    /// axes, and for flips, which keep the grid axis-aligned and are applied exactly where the
    /// mesh is written (the pipeline's `Mirror`).
    pub fn dropped(&self) -> Option<String> {
        match self {
            Orientation::Aligned | Orientation::Flipped(_) => None,
            Orientation::Rotated => Some(
                "the header rotates or permutes the axes, which isostream does not apply: the \
                 mesh is in voxel-index orientation from the header's origin (positions origin + \
                 spacing * (i, j, k), spacing the axes' step lengths), not in the header's \
                 physical space"
                    .to_string(),
            ),
        }
    }
}

/// The length of a step vector: an axis' spacing.
pub(crate) fn step_length(c: [f64; 3]) -> f64 {
    c.iter().map(|v| v * v).sum::<f64>().sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_tell_flips_from_rotations() {
        let diag = |a: f64, b: f64, c: f64| [[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, 0.0, c]];
        assert_eq!(
            Orientation::of_columns(diag(0.5, 0.8, 1.2)),
            Orientation::Aligned
        );
        assert_eq!(
            Orientation::of_columns(diag(-0.5, -0.8, 1.2)),
            Orientation::Flipped([true, true, false])
        );
        // f32 noise off the diagonal is not a rotation.
        let mut noisy = diag(-2.0, 1.0, 1.0);
        noisy[0][1] = 1e-7;
        assert_eq!(
            Orientation::of_columns(noisy),
            Orientation::Flipped([true, false, false])
        );
        let swapped = [[0.0, 2.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.5]];
        assert_eq!(Orientation::of_columns(swapped), Orientation::Rotated);
        let none = [[0.0; 3], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]];
        assert_eq!(
            Orientation::of_columns(none),
            Orientation::Flipped([false, true, false])
        );
    }

    #[test]
    fn dropped_says_what_and_where() {
        assert_eq!(Orientation::Aligned.dropped(), None);
        assert_eq!(Orientation::Flipped([true, false, true]).dropped(), None);
        let rot = Orientation::Rotated.dropped().unwrap();
        assert!(
            rot.contains("rotates") && rot.contains("voxel-index orientation"),
            "{rot}"
        );
    }
}
