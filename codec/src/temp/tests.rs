//! The temporaries' tests: lattice arrays in memory, mapped, named and persisted, their
//! windows and strided copies, and the pages they release.

use super::*;

#[test]
fn both_storages_hold_the_same_values_through_releases() {
    let len = MAPPED_WINDOW_BYTES as usize / 4 + 12345;
    for storage in [TempStorage::Memory, TempStorage::File(None)] {
        let mut a = LatticeArray::filled(len, -7i32, &storage).unwrap();
        assert_eq!(a.is_mapped(), storage != TempStorage::Memory);
        assert!(a.iter().all(|&v| v == -7));
        a[len - 1] = 99;
        a[17] = 5;
        a.release(0..len);
        a.touched(len);
        assert_eq!((a[17], a[len - 1], a[18]), (5, 99, -7));
        let mut sum = 0i64;
        a.for_each_window(|_, w| sum += w.iter().map(|&v| i64::from(v)).sum::<i64>());
        assert_eq!(sum, -7 * (len as i64 - 2) + 5 + 99);
        assert!(a.any(|&v| v == 99) && !a.any(|&v| v == 100));
        let b = LatticeArray::filled(5, false, &storage).unwrap();
        assert_eq!(&b[..], &[false; 5]);
        assert_eq!(a.clone(), a);
    }
}

/// Resident file-backed pages of this process, KiB (`RssFile` in `/proc/self/status`).
fn rss_file_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("RssFile:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// A pass over a mapped array four windows long, reporting what it reads, keeps about a
/// window resident; without the reports the whole array would be.
#[test]
fn passes_over_a_mapped_array_keep_about_a_window_resident() {
    let Some(before) = rss_file_kib() else {
        return; // no /proc: nothing to measure
    };
    let window = MAPPED_WINDOW_BYTES as usize;
    let len = 4 * window;
    let a = LatticeArray::filled(len, 1u8, &TempStorage::File(None)).unwrap();
    let mut peak = 0;
    let mut sum = 0u64;
    for chunk in (0..len).step_by(1 << 20) {
        sum += a[chunk..chunk + (1 << 20)]
            .iter()
            .map(|&v| u64::from(v))
            .sum::<u64>();
        a.touched(1 << 20);
        peak = peak.max(rss_file_kib().unwrap().saturating_sub(before));
    }
    assert_eq!(sum, len as u64);
    // Other tests' mappings come and go meanwhile: a margin of a window.
    assert!(peak < 2 * window as u64 / 1024, "{peak} KiB resident");
}

/// Windows and strided copies read the right values from a mapped array, and a window
/// takes memory for its rows only.
#[test]
fn windows_and_strided_copies_hold_their_points_and_no_more() {
    let (w, h) = (2048usize, 4096usize);
    let mut a = LatticeArray::filled(w * h, 0i32, &TempStorage::File(None)).unwrap();
    // Written a row at a time, each dropped once written (tests run side by side, and one
    // measures this process's resident file pages).
    for y in 0..h {
        for (x, v) in a[y * w..(y + 1) * w].iter_mut().enumerate() {
            *v = (y * w + x) as i32 * 7 + 1;
        }
        a.release(y * w..(y + 1) * w);
    }
    let anon = || -> Option<u64> {
        let status = std::fs::read_to_string("/proc/self/status").ok()?;
        let line = status.lines().find(|l| l.starts_with("RssAnon:"))?;
        line.split_whitespace().nth(1)?.parse().ok()
    };
    let before = anon();
    let rect = (100, 200, 299, 349);
    let win = a.window(w, rect).unwrap();
    if let (Some(b), Some(after)) = (before, anon()) {
        // 150 rows of 800 bytes: a page or two each (other tests allocate meanwhile).
        assert!(after.saturating_sub(b) < 8 << 10, "{} KiB", after - b);
    }
    for (x, y) in [
        (100, 200),
        (299, 349),
        (150, 300),
        (99, 200),
        (300, 349),
        (100, 199),
    ] {
        let inside = (100..=299).contains(&x) && (200..=349).contains(&y);
        let k = y * w + x;
        assert_eq!(win[k], if inside { a[k] } else { 0 }, "({x}, {y})");
    }
    // Clipped to the array; an empty rectangle gives zeros.
    let edge = a.window(w, (2000, 4000, 5000, 9000)).unwrap();
    assert_eq!(edge[w * h - 1], a[w * h - 1]);
    assert!(a.window(w, (10, 10, 5, 5)).unwrap().iter().all(|&v| v == 0));
    for shift in [0, 1, 3, 11] {
        let s = a.strided(w, shift).unwrap();
        let (cw, ch) = (((w - 1) >> shift) + 1, ((h - 1) >> shift) + 1);
        assert_eq!(s.len(), cw * ch);
        for (i, j) in [(0, 0), (cw - 1, ch - 1), (cw / 2, ch / 3)] {
            assert_eq!(s[j * cw + i], a[(j << shift) * w + (i << shift)], "{shift}");
        }
    }
}

/// The names in `dir`.
fn names(dir: &Path) -> Vec<String> {
    let mut n: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    n.sort();
    n
}

/// Persisting gives each storage's values a file, in the host's byte order; a named mapped
/// array's own file is renamed (it stays the array's: a later write shows in it), the
/// others are written out; no temporary is left; a file mapped back reads the same values.
#[test]
fn persisted_arrays_map_back_with_their_values() {
    let dir = tempfile::tempdir().unwrap();
    // Small: another test measures this process's resident file pages meanwhile.
    let len = 100_003;
    let storages = [
        TempStorage::Memory,
        TempStorage::File(None),
        TempStorage::Named(dir.path().to_path_buf()),
    ];
    for (k, storage) in storages.iter().enumerate() {
        let mut a = LatticeArray::filled(len, 0i32, storage).unwrap();
        for (i, v) in a.iter_mut().enumerate() {
            *v = (i as i32).wrapping_mul(2_654_435_761_u32 as i32);
        }
        if let TempStorage::Named(_) = storage {
            let temp = names(dir.path());
            assert!(
                temp.iter().any(|n| n.starts_with(LATTICE_TEMP_PREFIX)),
                "{temp:?}"
            );
        }
        let path = dir.path().join(format!("a{k}"));
        a.persist(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 4 * len);
        assert_eq!(bytes[4 * 7..4 * 8], a[7].to_ne_bytes());
        // A named mapped array is its file now: a write to it shows there.
        a[3] = 12345;
        let renamed = matches!(storage, TempStorage::Named(_));
        let now = std::fs::read(&path).unwrap();
        assert_eq!(
            now[12..16] == 12345i32.to_ne_bytes(),
            renamed,
            "{storage:?}"
        );
        assert!(
            !names(dir.path())
                .iter()
                .any(|n| n.starts_with(LATTICE_TEMP_PREFIX)),
            "a temporary left: {:?}",
            names(dir.path())
        );
        let file = std::fs::File::open(&path).unwrap();
        // SAFETY: an `i32` file nothing else writes meanwhile.
        let back = unsafe { LatticeArray::<i32>::map_file(file, len) }.unwrap();
        assert!(back.is_mapped() && back.windows() == cfg!(unix));
        assert_eq!(back[len - 1], a[len - 1]);
        assert_eq!(back.window(1000, (5, 2, 9, 3)).unwrap()[2005], a[2005]);
        // Another length than the file's is refused.
        let file = std::fs::File::open(&path).unwrap();
        // SAFETY: as above.
        let e = unsafe { LatticeArray::<i32>::map_file(file, len + 1) }.unwrap_err();
        assert!(e.to_string().contains("lattice file of"), "{e}");
    }
    // A named array dropped unpersisted leaves nothing.
    drop(LatticeArray::filled(10, 1u8, &storages[2]).unwrap());
    assert_eq!(names(dir.path()), ["a0", "a1", "a2"]);
}

/// A `bool` file holding other bytes than 0 and 1 (written by another process, damaged)
/// still reads as valid `bool`s through windows and strided copies (1 is true, the rest
/// false), which never read the mapping.
#[cfg(unix)]
#[test]
fn a_bool_file_with_other_bytes_reads_as_valid_bools_through_windows() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("valid");
    std::fs::write(&path, [0u8, 1, 2, 255, 1, 0, 7, 1]).unwrap();
    let file = std::fs::File::open(&path).unwrap();
    // SAFETY: read only through `window` and `strided`, which do not use the mapping.
    let a = unsafe { LatticeArray::<bool>::map_file(file, 8) }.unwrap();
    let w = a.window(4, (0, 0, 3, 1)).unwrap();
    let bytes: Vec<u8> = w.iter().map(|&b| u8::from(b)).collect();
    assert_eq!(bytes, [0, 1, 0, 0, 1, 0, 0, 1]);
    let s = a.strided(4, 1).unwrap();
    assert_eq!(s.iter().map(|&b| u8::from(b)).collect::<Vec<_>>(), [0, 0]);
}

#[test]
fn an_unusable_temporary_directory_is_an_error_not_a_panic() {
    let missing = std::env::temp_dir().join("cbdam-no-such-dir/sub");
    let err = LatticeArray::filled(4, 0u8, &TempStorage::File(Some(missing))).unwrap_err();
    assert!(err.to_string().contains("lattice"), "{err}");
}
