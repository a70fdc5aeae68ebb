//! The self-intersection guard on a real volume under the tightest memory budget a job may ask
//! for (when `../shared/data` is present): retirement for memory then writes triangles right
//! next to vertices that still contract, more of them than the guard keeps as obstacles.

mod common;

/// Bonsai at R = 0.01 with 16 MiB, one simplifier stage and two: valid and crossing-free. When
/// the guard forgot its oldest written triangles without refusing fans where they were, these
/// jobs wrote 4 (one stage) and 25 (two stages) crossing triangles; generated volumes of the
/// property tests never reached back that far.
#[test]
fn a_tight_budget_never_crosses_written_triangles() {
    let Some(volume) = common::shared_volume("bonsai/bonsai.vti") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for stages in [1, 2] {
        let job = dir.path().join(format!("job{stages}.toml"));
        let text = format!(
            "[input]\npath = \"{}\"\n\n[extract]\niso = 40\n\n[simplify]\nmode = \"rate\"\nrate = 0.01\n\n[output]\npath = \"out{stages}.smb\"\n\n[pipeline]\nsimplify_stages = {stages}\nmemory_budget_mib = 16\n",
            volume.display()
        );
        std::fs::write(&job, text).unwrap();
        let summary = common::run_job(&job);
        assert!(
            summary.simplify.forced_retirements > 0,
            "{:?}",
            summary.simplify
        );
        let mesh = common::Mesh::read(&dir.path().join(format!("out{stages}.smb")));
        assert!(mesh.check().is_valid_manifold(), "{:?}", mesh.check());
        let crossing = mesh.self_intersections();
        assert_eq!(crossing, 0, "{stages} stages: {:?}", summary.simplify);
    }
}

/// A straight tube along z (a prism: its sides are planar strips, where every contraction costs
/// nothing): decimated shortest edge first among (nearly) equal costs, its sides stay made of
/// short triangles, so the guard's queries meet a few neighbours each. In queue order they became
/// slivers spanning the tube's length, and each query met thousands (5,568 fan/record pairs a
/// query in the second stage at 300 voxels, 15,600 at 600: the run grew with the square of the
/// length, 241 s at 2,100). Counts, not time: the same on any machine. Valid and crossing-free
/// as ever.
#[test]
fn a_straight_tube_is_decimated_without_slivers_along_it() {
    let dims = [12u64, 12, 300];
    let mut data = Vec::with_capacity((dims[0] * dims[1] * dims[2]) as usize);
    for _z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (dx, dy) = (x as f32 - 5.5, y as f32 - 5.5);
                data.push(4.0 - (dx * dx + dy * dy).sqrt());
            }
        }
    }
    let volume = common::TestVolume {
        dims,
        data,
        iso: 0.0,
    };
    let dir = tempfile::tempdir().unwrap();
    let job = volume.job(dir.path(), "rate = 0.2", "tube.smb");
    let summary = common::run_job(&job);
    let stages = summary.simplify_stages.as_ref().map_or_else(
        || vec![summary.simplify.clone()],
        |s| s.to_vec(),
    );
    for s in &stages {
        let per_query = s.guard.pairs as f64 / s.guard.queries.max(1) as f64;
        assert!(per_query < 1000.0, "{per_query} pairs a query: {:?}", s.guard);
    }
    let mesh = common::Mesh::read(&dir.path().join("tube.smb"));
    // Triangles across one height of the tube: 1,274 at most in queue order, 118 now.
    let across = (0..dims[2])
        .map(|z| {
            let h = z as f64 + 0.5;
            let spans = |t: &[u32; 3]| {
                let z = t.map(|i| mesh.positions[i as usize][2]);
                z.iter().any(|&c| c < h) && z.iter().any(|&c| c > h)
            };
            mesh.triangles.iter().filter(|t| spans(t)).count()
        })
        .max()
        .unwrap_or(0);
    assert!(across < 400, "{across} triangles across one height of the tube");
    assert!(mesh.check().is_valid_manifold(), "{:?}", mesh.check());
    assert_eq!(mesh.self_intersections(), 0);
}
