//! The HUD's text: the viewer's figures as a few short lines, within the size the HUD's layout
//! budgets for ([`hud::MAX_LINES`] lines of at most [`hud::MAX_COLUMNS`] characters), so it
//! stays a small label in the window's corner.
//!
//! Cumulative counters (cache hits, records, requests) are written with k/M suffixes: they grow
//! for as long as the viewer runs and must not widen the box.

use cbdam_client::access::AccessStats;
use cbdam_client::controls::Mode;
use cbdam_client::refine::{CacheUse, FrameStats};
use cbdam_render::hud;
use cbdam_render::{CacheStats, DrawStats};

/// The GPU patch cache's occupancy and counters.
#[derive(Clone, Copy, Debug, Default)]
pub struct GpuCache {
    /// Slots holding a patch.
    pub resident: usize,
    /// Slots in the pool.
    pub capacity: u32,
    /// Counters since the renderer was made.
    pub stats: CacheStats,
}

/// What the HUD shows, gathered from the viewer each frame.
#[derive(Clone, Debug)]
pub struct Figures<'a> {
    /// The window's size, pixels.
    pub size: (u32, u32),
    /// The camera's controller.
    pub mode: Mode,
    /// The GPU adapter's name (as `wgpu` reports it).
    pub adapter: &'a str,
    /// Median of the last frame intervals, seconds (0: not measured yet).
    pub frame_s: f64,
    /// What the last frame drew.
    pub draw: DrawStats,
    /// What the last refinement step did.
    pub refine: FrameStats,
    /// The screen-space error target, pixels.
    pub pixel_error: f64,
    /// Refinement is stopped (F).
    pub frozen: bool,
    /// The refiner's CPU caches.
    pub cpu: CacheUse,
    /// The GPU patch cache (`None` before the window exists).
    pub gpu: Option<GpuCache>,
    /// The repository is fetched over the network (else read from a local file).
    pub remote: bool,
}

/// The HUD's lines: at most [`hud::MAX_LINES`], none longer than [`hud::MAX_COLUMNS`].
pub fn lines(f: &Figures<'_>) -> Vec<String> {
    let (d, r) = (&f.draw, &f.refine);
    let mode = match f.mode {
        Mode::Orbit => "orbit",
        Mode::Fly => "fly",
    };
    let title = format!("{mode} {}x{}  ", f.size.0, f.size.1);
    // The adapter's name without its driver details ("llvmpipe (LLVM 15.0.6, 256 bits)"),
    // shortened to what the line has room for; the full description is printed at start.
    let adapter = f.adapter.split(" (").next().unwrap_or_default();
    let room = hud::MAX_COLUMNS.saturating_sub(title.chars().count());
    let mut lines = vec![title + &adapter.chars().take(room).collect::<String>()];
    let triangles = format!("{:.3} Mtri", d.triangles as f64 / 1e6);
    lines.push(if f.frame_s > 0.0 {
        format!(
            "{:.1} fps {:.1} ms  {triangles} {:.1} M/s",
            1.0 / f.frame_s,
            f.frame_s * 1e3,
            d.triangles as f64 / f.frame_s / 1e6
        )
    } else {
        format!("fps: measuring  {triangles}")
    });
    lines.push(format!(
        "cut {} diamonds  {} halves  {} calls",
        count(r.refined as u64),
        count(d.patches as u64),
        d.draw_calls
    ));
    lines.push(format!(
        "drawn {}  culled {}  missing {}",
        count(d.drawn as u64),
        count(d.culled as u64),
        count(d.missing as u64)
    ));
    let state = if f.frozen {
        "  FROZEN"
    } else if !r.converged {
        "  refining"
    } else {
        ""
    };
    lines.push(format!(
        "target {} px  max {:.2} px{state}",
        f.pixel_error, r.max_screen_error_px
    ));
    lines.extend(cache_lines(f));
    lines.push(access_line(f));
    lines
}

/// The CPU and GPU caches' lines.
fn cache_lines(f: &Figures<'_>) -> Vec<String> {
    let c = &f.cpu;
    let mut lines = vec![format!(
        "CPU records {}/{} decoded {}/{} MiB",
        mib(c.record_bytes),
        mib(c.record_budget),
        mib(c.decoded_bytes),
        mib(c.decoded_budget)
    )];
    if let Some(g) = &f.gpu {
        lines.push(format!(
            "GPU slots {}/{}  hits {}",
            g.resident,
            g.capacity,
            count(g.stats.hits)
        ));
        lines.push(format!(
            "    uploads {}  evictions {}",
            count(g.stats.uploads),
            count(g.stats.evictions)
        ));
    }
    lines
}

/// The line of what was read: from the network or the file.
fn access_line(f: &Figures<'_>) -> String {
    let a: &AccessStats = &f.refine.access;
    if f.remote {
        format!(
            "net {} in flight {} req {}B {} err",
            a.in_flight,
            count(a.requests_issued),
            count(a.bytes_fetched),
            count(a.errors)
        )
    } else {
        format!(
            "file {} records  {}B",
            count(a.records_taken),
            count(a.bytes_fetched)
        )
    }
}

/// A count in at most 5 characters below 10¹²: `999`, `12.3k`, `123k`, `4.5M`, `123M`, `12.3G`.
fn count(n: u64) -> String {
    let n = n as f64;
    let (v, unit) = match n {
        n if n < 1e3 => return format!("{n}"),
        n if n < 1e6 => (n / 1e3, "k"),
        n if n < 1e9 => (n / 1e6, "M"),
        n => (n / 1e9, "G"),
    };
    if v < 99.95 {
        format!("{v:.1}{unit}")
    } else {
        format!("{v:.0}{unit}")
    }
}

/// Bytes as MiB: one decimal below 10 MiB, whole MiB above.
fn mib(bytes: usize) -> String {
    let m = bytes as f64 / f64::from(1u32 << 20);
    if m < 9.95 {
        format!("{m:.1}")
    } else {
        format!("{m:.0}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Figures at the large end of what a session shows: a 4K window, a cut of a hundred
    /// thousand diamonds, caches of GiBs, hours of cumulative counters, a long adapter name.
    fn large() -> Figures<'static> {
        let mut refine = FrameStats {
            refined: 123_456,
            max_screen_error_px: 123.45,
            ..FrameStats::default()
        };
        refine.access = AccessStats {
            requests_issued: 987_654_321,
            in_flight: 4096,
            records_taken: 987_654_321,
            bytes_fetched: 123_456_789_012,
            errors: 123_456,
            ..AccessStats::default()
        };
        Figures {
            size: (3840, 2160),
            mode: Mode::Orbit,
            adapter: "NVIDIA GeForce RTX 4090 Laptop GPU with a long marketing name (Vulkan)",
            frame_s: 1.0 / 1000.0,
            draw: DrawStats {
                patches: 246_912,
                drawn: 200_000,
                culled: 46_912,
                missing: 12_345,
                triangles: 99_999_999,
                draw_calls: 9999,
                ..DrawStats::default()
            },
            refine,
            pixel_error: 0.0625,
            frozen: true,
            cpu: CacheUse {
                record_bytes: 4000 << 20,
                record_budget: 4096 << 20,
                decoded_bytes: 4000 << 20,
                decoded_budget: 4096 << 20,
                decoded_evictions: 0,
            },
            gpu: Some(GpuCache {
                resident: 65_536,
                capacity: 65_536,
                stats: CacheStats {
                    hits: 12_345_678_901,
                    uploads: 987_654_321,
                    evictions: 987_654_321,
                    ..CacheStats::default()
                },
            }),
            remote: true,
        }
    }

    #[test]
    fn large_figures_fit_the_hud_budget() {
        let mut f = large();
        for (remote, frozen, frame_s) in [(true, true, 1e-3), (false, false, 0.0)] {
            (f.remote, f.frozen, f.frame_s) = (remote, frozen, frame_s);
            let lines = lines(&f);
            assert!(lines.len() <= hud::MAX_LINES, "{lines:#?}");
            for l in &lines {
                assert!(l.chars().count() <= hud::MAX_COLUMNS, "too long: {l:?}");
                assert!(l.is_ascii(), "the HUD's font is ASCII: {l:?}");
            }
        }
    }

    #[test]
    fn every_figure_is_shown() {
        let text = lines(&large()).join("\n");
        for figure in [
            "orbit",
            "3840x2160",
            "NVIDIA",
            "1000.0 fps",
            "1.0 ms",
            "100.000 Mtri",
            "100000.0 M/s",
            "123k diamonds",
            "247k halves",
            "9999 calls",
            "drawn 200k",
            "culled 46.9k",
            "missing 12.3k",
            "target 0.0625 px",
            "max 123.45 px",
            "FROZEN",
            "records 4000/4096",
            "decoded 4000/4096",
            "slots 65536/65536",
            "hits 12.3G",
            "uploads 988M",
            "evictions 988M",
            "4096 in flight",
            "988M req",
            "123GB",
            "123k err",
        ] {
            assert!(text.contains(figure), "no {figure:?} in\n{text}");
        }
        let mut f = large();
        (f.remote, f.frozen, f.frame_s) = (false, false, 0.0);
        let text = lines(&f).join("\n");
        for figure in ["fps: measuring", "refining", "file 988M records  123GB"] {
            assert!(text.contains(figure), "no {figure:?} in\n{text}");
        }
    }

    #[test]
    fn counts_stay_short() {
        let cases = [
            (0, "0"),
            (999, "999"),
            (1000, "1.0k"),
            (12_345, "12.3k"),
            (99_949, "99.9k"),
            (99_950, "100k"),
            (999_499, "999k"),
            (4_500_000, "4.5M"),
            (12_345_678_901, "12.3G"),
        ];
        for (n, text) in cases {
            assert_eq!(count(n), text);
        }
        assert_eq!(mib(3 << 19), "1.5");
        assert_eq!(mib(256 << 20), "256");
    }
}
