//! Hou and Chen's Table 1, transcribed with the paper's numbering and mapped onto our grid edges.
//!
//! The paper traverses "left to right on x, front to back on y, top to bottom on z" and numbers
//! corners and lines as in Lorensen and Cline, with corners 4..7 on the face traversed first
//! (the "top") and 0..3 on the face traversed last. In our coordinates (x fastest, then y, then z,
//! all increasing) that makes the paper's corner 4 our offset (0,0,0); the full mapping is in
//! [`PAPER_CORNER_OFFSET`]. Each line (cube edge) is then named by its lower corner and its axis,
//! which is exactly how [`isostream_extract::EdgeKey`] names grid edges.
//!
//! Only the "Modifiable line" column matters here: a vertex whose value equals the iso value sits
//! on a cube corner, but we keep it an edge vertex (its triangles still all lie in the four cubes
//! around its edge), so the corner column is subsumed.

/// The paper's corner numbering as offsets (dx, dy, dz) in our traversal coordinates.
const PAPER_CORNER_OFFSET: [[u64; 3]; 8] = [
    [0, 0, 1],
    [1, 0, 1],
    [1, 1, 1],
    [0, 1, 1],
    [0, 0, 0],
    [1, 0, 0],
    [1, 1, 0],
    [0, 1, 0],
];

/// The paper's lines as pairs of its corners (Lorensen and Cline numbering).
const PAPER_LINES: [[usize; 2]; 12] = [
    [0, 1],
    [1, 2],
    [2, 3],
    [3, 0],
    [4, 5],
    [5, 6],
    [6, 7],
    [7, 4],
    [0, 4],
    [1, 5],
    [2, 6],
    [3, 7],
];

/// The kinds of cube in Table 1, by which far boundaries of the volume they touch.
/// "Right" is the last cube along x, "back" along y, "bottom" along z.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CubeKind {
    Internal,
    RightBound,
    BackBound,
    BottomBound,
    RightBack,
    RightBottom,
    BackBottom,
    /// The last traversed cube: right, back and bottom at once.
    Last,
}

impl CubeKind {
    /// Classifies the cube whose lower corner is `coord` in a volume of `dims` voxels.
    pub fn of(coord: [u64; 3], dims: [u64; 3]) -> Self {
        let right = coord[0] + 2 == dims[0];
        let back = coord[1] + 2 == dims[1];
        let bottom = coord[2] + 2 == dims[2];
        match (right, back, bottom) {
            (false, false, false) => Self::Internal,
            (true, false, false) => Self::RightBound,
            (false, true, false) => Self::BackBound,
            (false, false, true) => Self::BottomBound,
            (true, true, false) => Self::RightBack,
            (true, false, true) => Self::RightBottom,
            (false, true, true) => Self::BackBottom,
            (true, true, true) => Self::Last,
        }
    }

    /// Table 1, "Modifiable line" column, in the paper's line numbers.
    fn paper_lines(self) -> &'static [usize] {
        match self {
            Self::Internal => &[4, 7, 8],
            Self::RightBound => &[4, 5, 7, 8, 9],
            Self::BackBound => &[4, 6, 7, 8, 11],
            Self::BottomBound => &[0, 3, 4, 7, 8],
            Self::RightBack => &[4, 5, 6, 7, 8, 9, 10, 11],
            Self::RightBottom => &[0, 1, 3, 4, 5, 7, 8, 9],
            Self::BackBottom => &[0, 2, 3, 4, 6, 7, 8, 11],
            Self::Last => &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11],
        }
    }
}

/// A paper line as (lower-corner offset, axis 0/1/2).
fn line_as_edge(line: usize) -> Line {
    let [a, b] = PAPER_LINES[line].map(|c| PAPER_CORNER_OFFSET[c]);
    let axis = (0..3)
        .find(|&i| a[i] != b[i])
        .expect("a line joins two corners") as u8;
    let lower = [a[0].min(b[0]), a[1].min(b[1]), a[2].min(b[2])];
    (lower, axis)
}

/// A cube edge as (lower-corner offset, axis).
type Line = ([u64; 3], u8);

static TABLE: std::sync::LazyLock<[Vec<Line>; 8]> = std::sync::LazyLock::new(|| {
    [
        CubeKind::Internal,
        CubeKind::RightBound,
        CubeKind::BackBound,
        CubeKind::BottomBound,
        CubeKind::RightBack,
        CubeKind::RightBottom,
        CubeKind::BackBottom,
        CubeKind::Last,
    ]
    .map(|k| k.paper_lines().iter().map(|&l| line_as_edge(l)).collect())
});

/// The cube edges (lower-corner offset, axis) whose vertices become modifiable once a cube of
/// this kind has been extracted.
pub fn modifiable_lines(kind: CubeKind) -> &'static [Line] {
    &TABLE[kind as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The edges a cube releases must be exactly those whose last adjacent cube (in traversal
    /// order) it is: the table transcription is checked against that first principle on a
    /// small grid, for every kind of cube.
    #[test]
    fn table_matches_last_adjacent_cube_rule() {
        let dims = [4u64, 5, 3];
        let cubes = |d: u64| d - 1;
        for z in 0..cubes(dims[2]) {
            for y in 0..cubes(dims[1]) {
                for x in 0..cubes(dims[0]) {
                    let mut expected = Vec::new();
                    for axis in 0..3u8 {
                        for dz in 0..2 {
                            for dy in 0..2 {
                                for dx in 0..2 {
                                    let off = [dx, dy, dz];
                                    if off[axis as usize] != 0 {
                                        continue;
                                    }
                                    let e = [x + dx, y + dy, z + dz];
                                    if last_cube_of_edge(e, axis, dims) == [x, y, z] {
                                        expected.push((off, axis));
                                    }
                                }
                            }
                        }
                    }
                    let mut got = modifiable_lines(CubeKind::of([x, y, z], dims)).to_vec();
                    got.sort();
                    expected.sort();
                    assert_eq!(got, expected, "cube {x},{y},{z}");
                }
            }
        }
    }

    /// The adjacent cube of edge `e` along `axis` that comes last in traversal order.
    fn last_cube_of_edge(e: [u64; 3], axis: u8, dims: [u64; 3]) -> [u64; 3] {
        let mut c = e;
        for i in 0..3 {
            if i != axis as usize {
                // Adjacent cubes have lower corner e[i]-1 or e[i]; the later one is e[i] if it
                // exists (e[i] <= dims-2), else e[i]-1.
                c[i] = e[i].min(dims[i] - 2);
            }
        }
        c
    }

    #[test]
    fn kinds_by_position() {
        let d = [4, 4, 4];
        assert_eq!(CubeKind::of([0, 0, 0], d), CubeKind::Internal);
        assert_eq!(CubeKind::of([2, 0, 0], d), CubeKind::RightBound);
        assert_eq!(CubeKind::of([0, 2, 0], d), CubeKind::BackBound);
        assert_eq!(CubeKind::of([0, 0, 2], d), CubeKind::BottomBound);
        assert_eq!(CubeKind::of([2, 2, 2], d), CubeKind::Last);
    }
}
