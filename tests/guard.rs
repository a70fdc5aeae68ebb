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
