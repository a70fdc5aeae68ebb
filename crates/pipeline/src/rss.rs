//! Resident memory as the operating system counts it.

/// Peak resident set size of this process in bytes (Linux `VmHWM`), if the OS tells.
pub fn peak_rss_bytes() -> Option<u64> {
    status_bytes("VmHWM:")
}

/// Resident set size of this process now, in bytes (Linux `VmRSS`), if the OS tells. Cheap
/// enough (one read of `/proc/self/status`, tens of microseconds) to be taken after every slab.
pub fn current_rss_bytes() -> Option<u64> {
    status_bytes("VmRSS:")
}

/// Physical memory of the machine in bytes (Linux `MemTotal`), if the OS tells.
pub(crate) fn physical_memory_bytes() -> Option<u64> {
    kib_line("/proc/meminfo", "MemTotal:")
}

/// A `kB` line of `/proc/self/status`, in bytes.
fn status_bytes(key: &str) -> Option<u64> {
    kib_line("/proc/self/status", key)
}

/// The `kB` value of the line starting with `key` in `file`, in bytes.
fn kib_line(file: &str, key: &str) -> Option<u64> {
    let status = std::fs::read_to_string(file).ok()?;
    let line = status.lines().find(|l| l.starts_with(key))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    #[test]
    #[cfg(target_os = "linux")]
    fn reads_plausible_values() {
        // Now first, then the peak. The kernel sums RSS from per-CPU counters that lag by a
        // batch of pages, so with other test threads allocating and freeing in between, the
        // peak read second once came out 126 KiB below the current value read first (a clean
        // clone's `.ci/run`): a slack of a few MiB, far below any run's memory.
        let now = super::current_rss_bytes().expect("VmRSS on Linux");
        let peak = super::peak_rss_bytes().expect("VmHWM on Linux");
        assert!(now > 1024 * 1024, "{now}");
        assert!(peak + 4 * 1024 * 1024 >= now, "{peak} < {now}");
        let total = super::physical_memory_bytes().expect("MemTotal on Linux");
        assert!(total > peak, "{total} <= {peak}");
    }
}
