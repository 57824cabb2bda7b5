//! The process's own peak resident memory so far (Linux `VmHWM`) and CPU time, for
//! `--timings` to say which step of a build set the peak and what each step cost.

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

/// The CPU time this process has used so far, user and system, seconds (`getrusage`); `None`
/// where the system does not say.
#[cfg(unix)]
pub fn cpu_seconds() -> Option<(f64, f64)> {
    // SAFETY: `getrusage` writes the zeroed struct it is given and reads nothing else.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return None;
    }
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Some((seconds(usage.ru_utime), seconds(usage.ru_stime)))
}

/// The CPU time this process has used so far: not known here.
#[cfg(not(unix))]
pub fn cpu_seconds() -> Option<(f64, f64)> {
    None
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

    /// The CPU time counts the work this test does, and never goes back.
    #[test]
    #[cfg(unix)]
    fn the_cpu_time_counts_work_done() {
        let (user0, sys0) = super::cpu_seconds().expect("Unix says");
        let used = || {
            let (user, sys) = super::cpu_seconds().expect("Unix says");
            assert!(
                user >= user0 && sys >= sys0,
                "{user0} {sys0} → {user} {sys}"
            );
            user + sys - user0 - sys0
        };
        // Spin until a tenth of a CPU-second is counted, or five seconds of wall time (a
        // loaded machine gives this thread a share of a core; a clock that never moves fails).
        let (start, mut x) = (std::time::Instant::now(), 1u64);
        while used() < 0.1 && start.elapsed().as_secs() < 5 {
            for _ in 0..100_000 {
                x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005) + 1);
            }
        }
        assert!(used() >= 0.1, "{:.3} CPU-s in 5 s of wall ({x})", used());
    }
}
