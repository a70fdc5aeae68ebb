//! Counts self-intersecting triangles (crossing or touching another; the crossing ones alone
//! too) of a binary little-endian PLY (float xyz first, any
//! further float vertex properties such as attributes, uchar/uint faces, as `isostream convert`
//! writes): `cargo run --release -p isostream-meshcheck --example
//! self_intersections -- mesh.ply`.

fn main() {
    let path = std::env::args()
        .nth(1)
        .expect("usage: self_intersections mesh.ply");
    let data = std::fs::read(&path).expect("readable PLY");
    let end = data
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("PLY header")
        + 11;
    let header = String::from_utf8_lossy(&data[..end]);
    let count = |name: &str| -> usize {
        header
            .lines()
            .find_map(|l| l.strip_prefix(&format!("element {name} ")))
            .and_then(|n| n.trim().parse().ok())
            .expect("element count")
    };
    let (nv, nf) = (count("vertex"), count("face"));
    // Bytes a vertex takes: its float properties (x, y, z, then attributes), 4 bytes each.
    let stride = 4 * header
        .lines()
        .skip_while(|l| !l.starts_with("element vertex"))
        .skip(1)
        .take_while(|l| l.starts_with("property"))
        .inspect(|l| {
            assert!(
                l.starts_with("property float"),
                "float vertex properties only: {l}"
            )
        })
        .count();
    let f32_at = |o: usize| f32::from_le_bytes(data[o..o + 4].try_into().unwrap());
    let u32_at = |o: usize| u32::from_le_bytes(data[o..o + 4].try_into().unwrap());
    let pos: Vec<[f64; 3]> = (0..nv)
        .map(|i| [0, 1, 2].map(|k| f64::from(f32_at(end + stride * i + 4 * k))))
        .collect();
    let mut o = end + stride * nv;
    let mut tris = Vec::with_capacity(nf);
    for _ in 0..nf {
        assert_eq!(data[o], 3, "triangles only");
        tris.push([0, 1, 2].map(|k| u32_at(o + 1 + 4 * k)));
        o += 13;
    }
    // The last field is what tools read: triangles meeting another, crossing or touching.
    let crossing = isostream_meshcheck::crossing_triangles(&pos, &tris);
    let n = isostream_meshcheck::self_intersections(&pos, &tris);
    println!("{path}: {nf} faces, {crossing} crossing, {n} self-intersecting");
}
