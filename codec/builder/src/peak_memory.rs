//! The process's own peak resident memory so far (Linux `VmHWM`), for `--timings` to say
//! which step of a build set the peak.

/// The peak resident set size of this process so far, bytes (`VmHWM` of
/// `/proc/self/status`); `None` where the system does not say.
pub fn peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line
        .trim_start_matches("VmHWM:")
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    /// The peak is at least the memory this test touches.
    #[test]
    #[cfg(target_os = "linux")]
    fn the_peak_counts_memory_touched() {
        let before = super::peak_rss().expect("Linux says");
        let touched = vec![1u8; 64 << 20];
        let after = super::peak_rss().expect("Linux says");
        assert!(after >= before && after >= (64 << 20), "{before} → {after}");
        assert_eq!(touched.iter().map(|&b| u64::from(b)).sum::<u64>(), 64 << 20);
    }
}
