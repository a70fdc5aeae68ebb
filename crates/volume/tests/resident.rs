//! Sweeping a memory-mapped raw file keeps resident memory flat: pages behind the front are
//! handed back to the kernel. Its own test binary, so no other test's mappings blur the numbers.

#[cfg(target_os = "linux")]
#[test]
fn raw_sweep_keeps_mapped_pages_bounded() {
    use isostream_volume::{Dtype, Endian, RawSpec, RawVolume, VolumeSource};
    use std::io::Write;

    // 64 slices of 1 MiB: without releasing, the whole 64 MiB would end up resident.
    let (nx, ny, nz) = (1024u64, 1024u64, 64u64);
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let path = dir.path().join("sweep.raw");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    let slice: Vec<u8> = (0..nx * ny).map(|i| (i % 251) as u8).collect();
    for _ in 0..nz {
        f.write_all(&slice).unwrap();
    }
    drop(f);

    let before = mapped_kib();
    let mut v = RawVolume::open(&RawSpec {
        path,
        dims: [nx, ny, nz],
        dtype: Dtype::U8,
        endian: Endian::Little,
        spacing: [1.0; 3],
        origin: [0.0; 3],
        header_bytes: 0,
    })
    .unwrap();
    let mut out = vec![0.0f32; (nx * ny) as usize];
    let mut peak = 0;
    for z in 0..nz {
        v.read_slice(z, &mut out).unwrap();
        peak = peak.max(mapped_kib().saturating_sub(before));
    }
    assert_eq!(out[250], 250.0);
    assert!(
        peak < 16 * 1024,
        "file-backed resident memory grew by {peak} KiB"
    );
}

/// File-backed and shared-memory resident KiB of this process (tmpfs files count as shmem).
#[cfg(target_os = "linux")]
fn mapped_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    status
        .lines()
        .filter(|l| l.starts_with("RssFile:") || l.starts_with("RssShmem:"))
        .filter_map(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        .sum()
}
