//! The streamed GeoTIFF source against the `tiff` crate's whole-image decode: every sample type,
//! stripped and tiled (edge tiles padded), none / Deflate / LZW / PackBits, BigTIFF, more than
//! one band of rows; and a damaged chunk named in a clear error.

use std::fs;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use cbdam_builder::input::{GeoTiffSource, Limits};
use cbdam_codec::CodecError;
use cbdam_codec::quant::{HeightGrid, QuantPlan};
use cbdam_codec::samples::SampleSource;
use tempfile::TempDir;
use tiff::decoder::{Decoder, DecodingResult};
use tiff::encoder::compression::{CompressionAlgorithm, Deflate, DeflateLevel, Lzw, Packbits};
use tiff::encoder::{Compression, TiffEncoder, colortype};

/// Every sample of the file, decoded whole by the `tiff` crate: the reference.
fn reference(path: &Path) -> Vec<f64> {
    let mut dec = Decoder::new(fs::File::open(path).unwrap()).unwrap();
    match dec.read_image().unwrap() {
        DecodingResult::I8(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::U8(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::U16(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::I32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::U32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F64(v) => v,
        _ => panic!("unexpected sample type"),
    }
}

/// All samples of one pass, checking the blocks are consecutive whole rows.
fn streamed(src: &dyn SampleSource) -> (Vec<f64>, usize) {
    let mut all = Vec::new();
    let mut blocks = 0;
    src.for_each_block(&mut |row, block| {
        assert_eq!(row * src.width(), all.len(), "blocks in order");
        assert_eq!(block.len() % src.width(), 0, "whole rows");
        all.extend_from_slice(block);
        blocks += 1;
        Ok(())
    })
    .unwrap();
    (all, blocks)
}

fn check(path: &Path, w: usize, h: usize, want: &[f64]) -> usize {
    let src = GeoTiffSource::open(path, None, &Limits::default()).unwrap();
    assert_eq!((src.width(), src.height()), (w, h));
    let reference = reference(path);
    assert_eq!(
        reference,
        want,
        "{}: the crate decodes the test file",
        path.display()
    );
    let (first, blocks) = streamed(&src);
    assert_eq!(first, reference, "{}", path.display());
    // A second pass (from the cache for small files) gives the same samples.
    assert_eq!(
        streamed(&src).0,
        reference,
        "{}: second pass",
        path.display()
    );
    blocks
}

/// A little-endian classic TIFF written by hand: tiles of `tw × th` (padding repeats a marker
/// the reader must drop), each compressed with `compression` (TIFF code).
fn tiled_tiff(
    w: usize,
    h: usize,
    (tw, th): (usize, usize),
    (bits, format): (u16, u16),
    compression: u16,
    sample: impl Fn(usize, usize) -> Vec<u8>,
) -> Vec<u8> {
    let mut bytes = b"II*\0\0\0\0\0".to_vec();
    let (tx, ty) = (w.div_ceil(tw), h.div_ceil(th));
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    let marker = vec![0x7f; usize::from(bits / 8)];
    for tr in 0..ty {
        for tc in 0..tx {
            let mut raw = Vec::new();
            for r in 0..th {
                for c in 0..tw {
                    let (y, x) = (tr * th + r, tc * tw + c);
                    raw.extend(if x < w && y < h {
                        sample(x, y)
                    } else {
                        marker.clone()
                    });
                }
            }
            offsets.push(bytes.len() as u32);
            let mut packed = Vec::new();
            match compression {
                1 => packed = raw,
                5 => {
                    Lzw.write_to(&mut packed, &raw).unwrap();
                }
                8 => {
                    Deflate::with_level(DeflateLevel::Fast)
                        .write_to(&mut packed, &raw)
                        .unwrap();
                }
                32773 => {
                    Packbits.write_to(&mut packed, &raw).unwrap();
                }
                _ => panic!("compression {compression}"),
            }
            bytes.extend(&packed);
            counts.push(packed.len() as u32);
        }
    }
    let longs = |v: &[u32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let short = |v: u16| v.to_le_bytes().to_vec();
    // (tag, type, count, value bytes), in tag order.
    let entries: Vec<(u16, u16, u32, Vec<u8>)> = vec![
        (256, 4, 1, longs(&[w as u32])),
        (257, 4, 1, longs(&[h as u32])),
        (258, 3, 1, short(bits)),
        (259, 3, 1, short(compression)),
        (262, 3, 1, short(1)),
        (277, 3, 1, short(1)),
        (322, 4, 1, longs(&[tw as u32])),
        (323, 4, 1, longs(&[th as u32])),
        (324, 4, offsets.len() as u32, longs(&offsets)),
        (325, 4, counts.len() as u32, longs(&counts)),
        (339, 3, 1, short(format)),
    ];
    let mut fields = Vec::new();
    for (tag, ty, count, val) in entries {
        let field = if val.len() <= 4 {
            let mut f = val;
            f.resize(4, 0);
            f
        } else {
            let at = bytes.len() as u32;
            bytes.extend(val);
            at.to_le_bytes().to_vec()
        };
        fields.push((tag, ty, count, field));
    }
    let ifd_at = bytes.len() as u32;
    bytes[4..8].copy_from_slice(&ifd_at.to_le_bytes());
    bytes.extend((fields.len() as u16).to_le_bytes());
    for (tag, ty, count, field) in fields {
        bytes.extend(tag.to_le_bytes());
        bytes.extend(ty.to_le_bytes());
        bytes.extend(count.to_le_bytes());
        bytes.extend(field);
    }
    bytes.extend(0u32.to_le_bytes());
    bytes
}

fn put(dir: &TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    fs::write(&p, bytes).unwrap();
    p
}

/// A deterministic field with both signs.
fn field(x: usize, y: usize) -> i64 {
    ((x * 7919 + y * 104_729) % 2001) as i64 - 1000
}

#[test]
fn tiled_every_type_and_compression_matches_the_whole_decode() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (75, 41);
    type Conv = fn(i64) -> (Vec<u8>, f64);
    let types: [(&str, (u16, u16), Conv); 8] = [
        ("u8", (8, 1), |v| (vec![v as u8], f64::from(v as u8))),
        ("i8", (8, 2), |v| (vec![v as i8 as u8], f64::from(v as i8))),
        ("u16", (16, 1), |v| {
            ((v as u16).to_le_bytes().to_vec(), f64::from(v as u16))
        }),
        ("i16", (16, 2), |v| {
            ((v as i16).to_le_bytes().to_vec(), f64::from(v as i16))
        }),
        ("u32", (32, 1), |v| {
            let u = (v + 5000) as u32 * 70_001;
            (u.to_le_bytes().to_vec(), f64::from(u))
        }),
        ("i32", (32, 2), |v| {
            let i = v as i32 * 1_000_003;
            (i.to_le_bytes().to_vec(), f64::from(i))
        }),
        ("f32", (32, 3), |v| {
            let f = v as f32 * 0.37 + 0.1;
            (f.to_le_bytes().to_vec(), f64::from(f))
        }),
        ("f64", (64, 3), |v| {
            let f = v as f64 * 0.013 - 0.7;
            (f.to_le_bytes().to_vec(), f)
        }),
    ];
    for (name, kind, conv) in types {
        let want: Vec<f64> = (0..w * h).map(|i| conv(field(i % w, i / w)).1).collect();
        // LZW is covered by the stripped files the `tiff` encoder writes.
        for compression in [1u16, 8, 32773] {
            for tile in [(16, 16), (32, 48)] {
                let bytes = tiled_tiff(w, h, tile, kind, compression, |x, y| conv(field(x, y)).0);
                let p = put(
                    &dir,
                    &format!("{name}_{compression}_{}.tif", tile.0),
                    &bytes,
                );
                check(&p, w, h, &want);
            }
        }
    }
}

#[test]
fn stripped_bigtiff_and_several_bands_match_the_whole_decode() {
    let dir = TempDir::new().unwrap();
    // Wide enough that one pass is several bands of rows (a band is about 2^20 samples).
    let (w, h) = (2000usize, 1100usize);
    let f32s: Vec<f32> = (0..w * h)
        .map(|i| field(i % w, i / w) as f32 * 0.25 + 0.125)
        .collect();
    let want: Vec<f64> = f32s.iter().map(|&v| f64::from(v)).collect();
    for (name, compression, big, rows) in [
        (
            "deflate_7",
            Compression::Deflate(DeflateLevel::Fast),
            false,
            7,
        ),
        ("lzw_big_64", Compression::Lzw, true, 64),
        ("packbits_1", Compression::Packbits, false, 1),
        ("none_big_1100", Compression::Uncompressed, true, 1100),
    ] {
        let mut out = Cursor::new(Vec::new());
        if big {
            let mut enc = TiffEncoder::new_big(&mut out)
                .unwrap()
                .with_compression(compression);
            let mut img = enc
                .new_image::<colortype::Gray32Float>(w as u32, h as u32)
                .unwrap();
            img.rows_per_strip(rows).unwrap();
            img.write_data(&f32s).unwrap();
        } else {
            let mut enc = TiffEncoder::new(&mut out)
                .unwrap()
                .with_compression(compression);
            let mut img = enc
                .new_image::<colortype::Gray32Float>(w as u32, h as u32)
                .unwrap();
            img.rows_per_strip(rows).unwrap();
            img.write_data(&f32s).unwrap();
        }
        let p = put(&dir, &format!("{name}.tif"), &out.into_inner());
        let blocks = check(&p, w, h, &want);
        if rows < 1100 {
            assert!(blocks > 1, "{name}: {blocks} block(s)");
        }
    }
}

#[test]
fn fused_plan_and_quantize_equal_the_separate_passes() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (1500usize, 800usize);
    // Decimetre lattice stored as float32 (a representation error), with nodata holes.
    let f32s: Vec<f32> = (0..w * h)
        .map(|i| {
            if i % 97 == 3 {
                -9999.0
            } else {
                (field(i % w, i / w) + 8123) as f32 / 10.0
            }
        })
        .collect();
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out)
        .unwrap()
        .with_compression(Compression::Lzw);
    let mut img = enc
        .new_image::<colortype::Gray32Float>(w as u32, h as u32)
        .unwrap();
    img.encoder()
        .write_tag(tiff::tags::Tag::GdalNodata, "-9999")
        .unwrap();
    img.rows_per_strip(3).unwrap();
    img.write_data(&f32s).unwrap();
    let p = put(&dir, "lattice.tif", &out.into_inner());
    for caching in [true, false] {
        let mut src = GeoTiffSource::open(&p, None, &Limits::default()).unwrap();
        src.set_caching(caching);
        assert_eq!(src.nodata(), Some(-9999.0));
        for (eps, quantum) in [(0.05, None), (0.3, None), (1.0, None), (0.5, Some(0.1))] {
            let plan = QuantPlan::for_source(&src, eps, quantum).unwrap();
            let grid = HeightGrid::from_source(&src, &plan).unwrap();
            let (fused_plan, fused_grid) = QuantPlan::quantize_source(&src, eps, quantum).unwrap();
            assert_eq!(plan, fused_plan, "ε {eps}");
            // At 0.3 m the representation error costs the lattice plan a step (0.5 m instead of
            // 0.7) and the float plan's 0.59 m step is coarser: both paths choose it.
            if eps == 0.3 {
                assert!(!plan.lattice, "{plan:?}");
            } else {
                assert!(plan.lattice && plan.representation_error > 0.0, "{plan:?}");
            }
            assert_eq!(grid, fused_grid, "ε {eps}");
        }
        // A quantum the data does not honour fails the same way on both paths.
        let separate = QuantPlan::for_source(&src, 1.0, Some(0.25))
            .and_then(|plan| HeightGrid::from_source(&src, &plan).map(|_| ()))
            .unwrap_err();
        let fused = QuantPlan::quantize_source(&src, 1.0, Some(0.25)).unwrap_err();
        assert_eq!(separate.to_string(), fused.to_string());
    }
}

#[test]
fn a_damaged_or_vanished_chunk_is_an_error_naming_file_and_chunk() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (64usize, 40usize);
    let bytes = tiled_tiff(w, h, (16, 16), (16, 2), 8, |x, y| {
        (field(x, y) as i16).to_le_bytes().to_vec()
    });
    // Overwrite the middle of the compressed data of tile 5 with garbage.
    let p = put(&dir, "good.tif", &bytes);
    let good = GeoTiffSource::open(&p, None, &Limits::default()).unwrap();
    assert_eq!(streamed(&good).0, reference(&p));
    let offsets_at = {
        // The tile offsets array is the first out-of-line value the writer placed after the
        // tiles; find it through the IFD entry 324.
        let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
        let n = u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]) as usize;
        let at = (0..n)
            .map(|e| ifd + 2 + 12 * e)
            .find(|&at| u16::from_le_bytes([bytes[at], bytes[at + 1]]) == 324)
            .unwrap();
        u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap()) as usize
    };
    let tile = |i: usize| {
        u32::from_le_bytes(
            bytes[offsets_at + 4 * i..offsets_at + 4 * i + 4]
                .try_into()
                .unwrap(),
        ) as usize
    };
    let mut bad = bytes.clone();
    for b in &mut bad[tile(5) + 2..tile(6)] {
        *b = 0xff;
    }
    let p = put(&dir, "damaged.tif", &bad);
    let src = GeoTiffSource::open(&p, None, &Limits::default()).unwrap();
    let e = src.for_each_block(&mut |_, _| Ok(())).unwrap_err();
    let msg = e.to_string();
    assert!(
        // The `tiff` crate reports a damaged Deflate stream as an I/O error of kind Other.
        matches!(
            e,
            CodecError::Corrupt(_) | CodecError::Truncated(_) | CodecError::Io(_)
        ),
        "{e}"
    );
    assert!(
        msg.contains("damaged.tif") && msg.contains("TIFF tile 5"),
        "{msg}"
    );
    assert!(msg.contains("rows 16..32, columns 16..32"), "{msg}");

    // The file cut short after it was opened (the chunk table said it was whole).
    let p = put(&dir, "shrinks.tif", &bytes);
    let src = GeoTiffSource::open(&p, None, &Limits::default()).unwrap();
    let f = fs::OpenOptions::new().write(true).open(&p).unwrap();
    f.set_len(tile(3) as u64 + 5).unwrap();
    drop(f);
    let e = src.for_each_block(&mut |_, _| Ok(())).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("shrinks.tif") && msg.contains("TIFF tile"),
        "{msg}"
    );
}
