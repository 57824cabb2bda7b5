//! Tests of the prepared grid's files, tile checks and summary.

use std::fs;
use std::path::Path;

use cbdam_codec::geometry::DiamondId;
use cbdam_codec::hierarchy::{GridSummary, Resolution};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::temp::TempStorage;

use super::summary::SUMMARY;
use super::tiles::{TILE, Tiling, WrittenCrcs, tile_crcs};
use super::{ARRAYS, HEAD, PREPARED, read_prepared, read_summary, write_prepared, write_summary};
use crate::error::Result;

/// A `w` × `h` grid with nodata here and there, and classes when `variable`.
fn grid(w: usize, h: usize) -> HeightGrid {
    let mut g = HeightGrid::all_valid(
        w,
        h,
        (0..w * h)
            .map(|k| (k * 7919 % 10007) as i32 - 5000)
            .collect(),
    );
    for k in (0..w * h).step_by(37) {
        g.valid[k] = false;
    }
    g
}

/// The prepared grid of `dir` with the tiles under `rects` checked.
fn read(
    dir: &Path,
    dims: (usize, usize, bool),
    rects: Option<&[(i64, i64, i64, i64)]>,
) -> Result<(HeightGrid, Option<Resolution>)> {
    let mut p = read_prepared(dir, dims)?;
    p.tiles.check(rects)?;
    Ok((p.grid, p.classes))
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut n: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    n.sort();
    n
}

/// A write that fails leaves no temporary behind (a full disk would leave gigabytes), from
/// a grid in memory (written out) and from one in named mapped files in the work directory
/// (renamed), once the grid is dropped: here the final name of the heights is taken by a
/// directory.
#[test]
fn a_failed_write_leaves_nothing_behind() {
    for named in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        fs::create_dir(dir.path().join(ARRAYS[0].0)).unwrap();
        let mut g = grid(40, 30);
        if named {
            g = g
                .copied_to(&TempStorage::Named(dir.path().to_path_buf()))
                .unwrap();
        }
        assert!(write_prepared(dir.path(), &mut g, None, None).is_err());
        // The arrays not yet renamed are the grid's own files until it is dropped.
        drop(g);
        assert_eq!(names(dir.path()), [ARRAYS[0].0], "named: {named}");
    }
    let dir = tempfile::tempdir().unwrap();
    fs::create_dir(dir.path().join(PREPARED)).unwrap();
    assert!(crate::journal::write_atomically(dir.path(), PREPARED, b"x").is_err());
    assert_eq!(names(dir.path()), [PREPARED]);
}

/// The grid reads back whole; a step checks only the tiles under its rectangles and reads
/// their points; a grid made in named mapped files is renamed into the work directory.
#[test]
fn a_step_checks_the_tiles_under_its_rectangles_and_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (2 * TILE + 17, TILE + 3);
    let g = grid(w, h);
    let classes = Resolution {
        class: (0..w * h)
            .map(|k| (k % 3) as u8)
            .collect::<Vec<u8>>()
            .into(),
    };
    for (variable, named) in [(false, false), (true, false), (true, true)] {
        let named_in = TempStorage::Named(dir.path().to_path_buf());
        let (mut g, mut c) = (g.clone(), classes.clone());
        if named {
            g = g.copied_to(&named_in).unwrap();
            c.class = c.class.copied_to(&named_in).unwrap();
        }
        let c = variable.then_some(&mut c);
        write_prepared(dir.path(), &mut g, c, None).unwrap();
        let mut want = vec![PREPARED, ARRAYS[0].0, ARRAYS[1].0];
        if variable {
            want.push(ARRAYS[2].0);
        }
        want.sort();
        assert_eq!(
            names(dir.path()),
            want,
            "variable {variable}, named {named}"
        );
        let (all, all_c) = read(dir.path(), (w, h, variable), None).unwrap();
        assert!(all == g, "the whole grid reads back");
        assert_eq!(
            all_c.map(|r| r.class.to_vec()),
            variable.then(|| classes.class.to_vec())
        );
        let t = TILE as i64;
        for rect in [(2 * t + 5, t + 1, 9 * t, 9 * t), (t - 1, -5, t + 4, t)] {
            let (part, part_c) = read(dir.path(), (w, h, variable), Some(&[rect])).unwrap();
            let values = part.values.window(w, rect).unwrap();
            let valid = part.valid.window(w, rect).unwrap();
            let (x0, y0) = (rect.0.max(0) as usize, rect.1.max(0) as usize);
            let (x1, y1) = ((rect.2 as usize).min(w - 1), (rect.3 as usize).min(h - 1));
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let k = y * w + x;
                    assert_eq!((values[k], valid[k]), (g.values[k], g.valid[k]));
                }
            }
            if let Some(pc) = part_c {
                assert_eq!(
                    pc.class.window(w, rect).unwrap()[y1 * w + x1],
                    classes.class[y1 * w + x1]
                );
            }
        }
    }
}

/// A damaged tile is refused when a step's rectangles cover it, naming it, and does not
/// matter when they do not; so is a validity byte other than 0 or 1 (which a `bool` cannot
/// hold); another size than the plan's, or an array cut short, is refused.
#[test]
fn damaged_tiles_and_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (2 * TILE + 17, TILE + 3);
    write_prepared(dir.path(), &mut grid(w, h), None, None).unwrap();
    let read = |rect: (i64, i64, i64, i64)| {
        super::tests::read(dir.path(), (w, h, false), Some(&[rect])).map(|_| ())
    };
    let t = TILE as i64;
    let damage = |name: &str, at: usize, byte: Option<u8>| {
        let path = dir.path().join(name);
        let good = fs::read(&path).unwrap();
        let mut bytes = good.clone();
        bytes[at] = byte.unwrap_or(bytes[at] ^ 1);
        fs::write(&path, &bytes).unwrap();
        good
    };
    // Heights of point (TILE + 3, 0): tile (1, 0).
    let good = damage(ARRAYS[0].0, 4 * (TILE + 3), None);
    let e = read((t, 0, t, 0)).unwrap_err().to_string();
    assert!(e.contains("checksum mismatch in tile (1, 0)"), "{e}");
    assert!(read((0, t, 10, t)).is_ok());
    fs::write(dir.path().join(ARRAYS[0].0), &good).unwrap();
    // Validity of point (2 TILE + 1, TILE + 2): tile (2, 1).
    let good = damage(ARRAYS[1].0, (TILE + 2) * w + 2 * TILE + 1, Some(2));
    let e = read((2 * t, t, 2 * t, t)).unwrap_err().to_string();
    assert!(e.contains("a validity byte 2 in tile (2, 1)"), "{e}");
    assert!(read((0, 0, t, t)).is_ok());
    fs::write(dir.path().join(ARRAYS[1].0), &good).unwrap();
    assert!(read((0, 0, 3 * t, 2 * t)).is_ok());
    let e = read_prepared(dir.path(), (w, h + 1, false))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("does not match the plan"), "{e}");
    let path = dir.path().join(ARRAYS[1].0);
    fs::write(&path, &good[..good.len() - 1]).unwrap();
    let e = read((0, 0, 0, 0)).unwrap_err().to_string();
    assert!(e.contains("prepared.valid") && e.contains("length"), "{e}");
    let header = dir.path().join(PREPARED);
    let mut bytes = fs::read(&header).unwrap();
    bytes[HEAD + 1] ^= 1;
    fs::write(&header, &bytes).unwrap();
    let e = read((0, 0, 0, 0)).unwrap_err().to_string();
    assert!(e.contains("checksum mismatch in its header"), "{e}");
}

/// The CRCs computed from the rows as they are written, in blocks of any size, equal
/// those read from the files (a grid a few tiles wide with a ragged last tile, with and
/// without classes); a second pass from row 0 starts over; rows out of order, missing or
/// of another size give none, so the files are read instead.
#[test]
fn crcs_of_the_rows_written_equal_the_files_ones() {
    let (w, h) = (2 * TILE + 17, 2 * TILE + 3);
    let g = grid(w, h);
    let class: Vec<u8> = (0..w * h).map(|k| (k * 31 % 7) as u8).collect();
    let t = |classes| Tiling {
        width: w,
        height: h,
        classes,
    };
    let dir = tempfile::tempdir().unwrap();
    let files = |classes: bool| {
        let mut paths = vec![ARRAYS[0].0, ARRAYS[1].0];
        fs::write(
            dir.path().join(ARRAYS[0].0),
            bytemuck::cast_slice(&g.values[..]),
        )
        .unwrap();
        fs::write(
            dir.path().join(ARRAYS[1].0),
            bytemuck::cast_slice(&g.valid[..]),
        )
        .unwrap();
        if classes {
            fs::write(dir.path().join(ARRAYS[2].0), &class).unwrap();
            paths.push(ARRAYS[2].0);
        }
        paths
            .iter()
            .map(|p| fs::File::open(dir.path().join(p)).unwrap())
            .collect::<Vec<_>>()
    };
    let feed = |c: &mut WrittenCrcs, block: usize, rows: std::ops::Range<usize>| {
        for y in rows.clone().step_by(block) {
            let ys = y..(y + block).min(rows.end);
            c.class_rows((w, h), &class[ys.start * w..ys.end * w], ys.clone());
            c.grid_rows(&g, ys);
        }
    };
    for classes in [false, true] {
        let want: Vec<u32> = tile_crcs(
            &t(classes),
            &files(classes),
            &vec![true; t(classes).count()],
        )
        .unwrap()
        .into_iter()
        .map(Option::unwrap)
        .collect();
        for block in [1, 7, TILE, 300, h] {
            let mut c = WrittenCrcs::default();
            feed(&mut c, block, 0..h);
            assert_eq!(
                c.finish(classes).as_ref(),
                Some(&want),
                "blocks of {block} rows"
            );
        }
        let mut again = WrittenCrcs::default();
        feed(&mut again, 50, 0..100);
        feed(&mut again, 64, 0..h);
        assert_eq!(again.finish(classes), Some(want.clone()), "a second pass");
    }
    let mut short = WrittenCrcs::default();
    feed(&mut short, 64, 0..h - 1);
    assert_eq!(short.finish(false), None, "a row missing");
    let mut skipped = WrittenCrcs::default();
    feed(&mut skipped, 64, 0..64);
    feed(&mut skipped, 64, 128..h);
    assert_eq!(skipped.finish(false), None, "rows skipped");
    let mut other = WrittenCrcs::default();
    feed(&mut other, 64, 0..h);
    other.class_rows((w + 1, h), &vec![0; w + 1], 0..1);
    assert_eq!(other.finish(true), None, "rows of another size");
    let mut no_classes = WrittenCrcs::default();
    for y in 0..h {
        no_classes.grid_rows(&g, y..y + 1);
    }
    assert_eq!(no_classes.finish(true), None, "classes never written");
    assert!(no_classes.finish(false).is_some());
}

/// Tiles are checked as a step comes to them: a damaged tile is found only by the check
/// that covers it, and a tile is read once however many checks cover it.
#[test]
fn tiles_are_checked_when_a_step_comes_to_them() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (3 * TILE, 2 * TILE);
    write_prepared(dir.path(), &mut grid(w, h), None, None).unwrap();
    let t = TILE as i64;
    let mut p = read_prepared(dir.path(), (w, h, false)).unwrap();
    p.tiles.check(Some(&[(0, 0, t - 1, t - 1)])).unwrap();
    // Damage tile (0, 0), already checked, and tile (2, 1), not yet.
    let path = dir.path().join(ARRAYS[0].0);
    let mut bytes = fs::read(&path).unwrap();
    bytes[0] ^= 1;
    bytes[4 * ((TILE + 1) * w + 2 * TILE + 1)] ^= 1;
    fs::write(&path, &bytes).unwrap();
    p.tiles.check(Some(&[(0, 0, 2 * t - 1, t - 1)])).unwrap();
    let e = p
        .tiles
        .check(Some(&[(2 * t, t, 2 * t, t)]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch in tile (2, 1)"), "{e}");
    let e = read(dir.path(), (w, h, false), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch in tile (0, 0)"), "{e}");
}

#[test]
fn a_summary_reads_back_and_a_damaged_one_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let id = |l, x, y| DiamondId::on_face(0, l, x, y);
    let s = GridSummary {
        max_abs: 1234,
        all_valid: false,
        nodata_mask: true,
        stored: vec![vec![id(0, 4, 4)], vec![id(1, 2, 4), id(1, 6, 4)]],
        recorded: Some(vec![vec![id(0, 4, 4)], vec![]]),
        root_field: vec![1, -2, 3, 4],
        roots: vec![9, 8, 7],
    };
    write_summary(dir.path(), &s).unwrap();
    assert_eq!(read_summary(dir.path()).unwrap(), s);
    let path = dir.path().join(SUMMARY);
    let mut bytes = fs::read(&path).unwrap();
    bytes[12] ^= 1;
    fs::write(&path, &bytes).unwrap();
    let e = read_summary(dir.path()).err().unwrap().to_string();
    assert!(e.contains("is damaged"), "{e}");
}
