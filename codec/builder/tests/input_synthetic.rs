//! The readers on small files written here, where the expected grid is known by construction:
//! good reads of every format and variant, and a clear error for every kind of bad input.

use std::fs;
use std::io::Cursor;
use std::path::{Path, PathBuf};

use cbdam_builder::input::{Format, Limits, ReadOptions, read_dem};
use cbdam_codec::CodecError;
use cbdam_codec::samples::{Dem, SampleType, detect_quantum};
use tempfile::TempDir;
use tiff::encoder::compression::DeflateLevel;
use tiff::encoder::{Compression, TiffEncoder, colortype};
use tiff::tags::{Predictor, Tag};

fn opts(format: Option<Format>) -> ReadOptions {
    ReadOptions {
        format,
        ..ReadOptions::default()
    }
}

fn read(path: &Path) -> Result<Dem, CodecError> {
    read_dem(path, &ReadOptions::default())
}

fn write(dir: &TempDir, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    fs::write(&p, bytes).unwrap();
    p
}

/// A deterministic field with both signs and no lattice coarser than 1.
fn ramp(w: usize, h: usize) -> Vec<i32> {
    (0..w * h).map(|i| (i as i32 * 37) % 2001 - 1000).collect()
}

// ---------------------------------------------------------------------------------------------
// SRTM .hgt

fn hgt_bytes(side: usize, f: impl Fn(usize) -> i16) -> Vec<u8> {
    (0..side * side).flat_map(|i| f(i).to_be_bytes()).collect()
}

#[test]
fn hgt_reads_big_endian_with_georef_from_name() {
    let dir = TempDir::new().unwrap();
    let side = 1201;
    let f = |i: usize| {
        if i == 5 {
            -32768
        } else {
            (i % 9000) as i16 - 500
        }
    };
    let p = write(&dir, "N39E040.hgt", &hgt_bytes(side, f));
    let dem = read(&p).unwrap();
    assert_eq!((dem.width, dem.height), (side, side));
    assert_eq!(dem.sample_type, SampleType::I16);
    assert!(
        dem.values
            .iter()
            .enumerate()
            .all(|(i, &v)| v == f64::from(f(i)))
    );
    // 0x01F4 = 500 would read as 0xF401 little-endian.
    assert_eq!(dem.values[1000], 500.0);
    assert_eq!(dem.nodata, Some(-32768.0));
    assert!(!dem.is_valid(5));
    assert!(dem.is_valid(6));
    let g = dem.georef.clone().unwrap();
    assert_eq!(g.epsg, Some(4326));
    assert_eq!((g.origin_x, g.origin_y), (40.0, 40.0));
    assert_eq!(g.pixel_x, 1.0 / 1200.0);
    assert!(!g.pixel_is_area);
    assert_eq!(detect_quantum(&dem), Some(1.0));
}

#[test]
fn hgt_southern_western_name_and_unparsable_name() {
    let dir = TempDir::new().unwrap();
    let bytes = hgt_bytes(1201, |i| (i % 7) as i16);
    let g = read(&write(&dir, "s12w077.hgt", &bytes))
        .unwrap()
        .georef
        .unwrap();
    assert_eq!((g.origin_x, g.origin_y), (-77.0, -11.0));
    assert!(
        read(&write(&dir, "tile.hgt", &bytes))
            .unwrap()
            .georef
            .is_none()
    );
}

#[test]
fn hgt_wrong_length_is_truncated() {
    let dir = TempDir::new().unwrap();
    let mut bytes = hgt_bytes(1201, |_| 1);
    bytes.truncate(bytes.len() - 2);
    let e = read(&write(&dir, "N00E000.hgt", &bytes)).unwrap_err();
    assert!(matches!(e, CodecError::Truncated(_)), "{e}");
    assert!(e.to_string().contains("2884802"), "{e}");
}

#[test]
fn hgt_over_the_sample_limit() {
    let dir = TempDir::new().unwrap();
    let p = write(&dir, "N00E000.hgt", &hgt_bytes(1201, |_| 1));
    let o = ReadOptions {
        limits: Limits {
            max_samples: 1201 * 1201 - 1,
        },
        ..ReadOptions::default()
    };
    assert!(matches!(
        read_dem(&p, &o),
        Err(CodecError::LimitExceeded(_))
    ));
}

// ---------------------------------------------------------------------------------------------
// ESRI ASCII grid

#[test]
fn ascii_grid_corner_integers() {
    let dir = TempDir::new().unwrap();
    let text = "ncols 3\nNROWS 2\nxllcorner 100.0\nyllcorner 200.0\ncellsize 10\n\
                NODATA_value -9999\n1 2 3\n4 -9999 -6\n";
    let dem = read(&write(&dir, "g.asc", text.as_bytes())).unwrap();
    assert_eq!((dem.width, dem.height), (3, 2));
    assert_eq!(dem.values, vec![1.0, 2.0, 3.0, 4.0, -9999.0, -6.0]);
    assert_eq!(dem.sample_type, SampleType::I32);
    assert_eq!(dem.nodata, Some(-9999.0));
    assert!(!dem.is_valid(4));
    let g = dem.georef.clone().unwrap();
    // North-west corner: the south edge plus two rows of 10.
    assert_eq!((g.origin_x, g.origin_y), (100.0, 220.0));
    assert_eq!((g.pixel_x, g.pixel_y), (10.0, 10.0));
    assert!(g.pixel_is_area);
    assert_eq!(g.epsg, None);
    assert_eq!(detect_quantum(&dem), Some(1.0));
}

#[test]
fn ascii_grid_centre_floats() {
    let dir = TempDir::new().unwrap();
    let text = "ncols 2\nnrows 3\nxllcenter 5\nyllcenter 7\ncellsize 0.5\n\
                0.5 1.5\n2.25 nan\n-3.75 4\n";
    let dem = read(&write(&dir, "f.asc", text.as_bytes())).unwrap();
    assert_eq!(dem.sample_type, SampleType::F64);
    assert_eq!(dem.nodata, None);
    assert!(dem.values[3].is_nan() && !dem.is_valid(3));
    assert_eq!(dem.values[4], -3.75);
    let g = dem.georef.clone().unwrap();
    assert_eq!((g.origin_x, g.origin_y), (5.0, 8.0));
    assert!(!g.pixel_is_area);
    assert_eq!(detect_quantum(&dem), Some(0.25));
}

#[test]
fn ascii_grid_bad_inputs() {
    let dir = TempDir::new().unwrap();
    let head = "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    let e = read(&write(
        &dir,
        "short.asc",
        format!("{head}1 2 3\n4 5").as_bytes(),
    ))
    .unwrap_err();
    assert!(matches!(e, CodecError::Truncated(_)), "{e}");
    let e = read(&write(
        &dir,
        "long.asc",
        format!("{head}1 2 3 4 5 6 7").as_bytes(),
    ))
    .unwrap_err();
    assert!(matches!(e, CodecError::Corrupt(_)), "{e}");
    let e = read(&write(
        &dir,
        "word.asc",
        format!("{head}1 2 x 4 5 6").as_bytes(),
    ))
    .unwrap_err();
    assert!(matches!(e, CodecError::Corrupt(_)), "{e}");
    let e = read(&write(
        &dir,
        "nocell.asc",
        b"ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\n5",
    ))
    .unwrap_err();
    assert!(e.to_string().contains("cellsize"), "{e}");
    let huge = "ncols 100000\nnrows 100000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3";
    let o = ReadOptions {
        limits: Limits {
            max_samples: 1 << 20,
        },
        ..ReadOptions::default()
    };
    let e = read_dem(&write(&dir, "huge.asc", huge.as_bytes()), &o).unwrap_err();
    assert!(matches!(e, CodecError::LimitExceeded(_)), "{e}");
    // Within the default limit the same header is simply short of data, and must not try to
    // reserve ten billion samples first.
    let e = read(&dir.path().join("huge.asc")).unwrap_err();
    assert!(
        matches!(e, CodecError::LimitExceeded(_) | CodecError::Truncated(_)),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------------
// Raw f32

#[test]
fn raw_f32_reads_little_endian_exactly() {
    let dir = TempDir::new().unwrap();
    let vals: Vec<f32> = (0..12).map(|i| i as f32 * 0.1 - 0.35).collect();
    let bytes: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
    let p = write(&dir, "x.raw", &bytes);
    let dem = read_dem(
        &p,
        &opts(Some(Format::RawF32 {
            width: 4,
            height: 3,
        })),
    )
    .unwrap();
    assert_eq!(
        (dem.width, dem.height, dem.sample_type),
        (4, 3, SampleType::F32)
    );
    assert!(
        dem.values
            .iter()
            .zip(&vals)
            .all(|(&a, &b)| a == f64::from(b))
    );
    assert!(dem.georef.is_none());

    // No size: a raw file cannot be read without a format.
    let e = read(&p).unwrap_err();
    assert!(matches!(e, CodecError::InvalidParameter(_)), "{e}");
    let e = read_dem(
        &p,
        &opts(Some(Format::RawF32 {
            width: 4,
            height: 4,
        })),
    )
    .unwrap_err();
    assert!(matches!(e, CodecError::Truncated(_)), "{e}");
    let e = read_dem(
        &p,
        &opts(Some(Format::RawF32 {
            width: 3,
            height: 3,
        })),
    )
    .unwrap_err();
    assert!(matches!(e, CodecError::InvalidParameter(_)), "{e}");
    let e = read_dem(
        &p,
        &opts(Some(Format::RawF32 {
            width: usize::MAX,
            height: 2,
        })),
    )
    .unwrap_err();
    assert!(matches!(e, CodecError::LimitExceeded(_)), "{e}");
}

// ---------------------------------------------------------------------------------------------
// PNG

fn png_bytes(w: u32, h: u32, color: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(color);
    enc.set_depth(depth);
    let mut wr = enc.write_header().unwrap();
    wr.write_image_data(data).unwrap();
    wr.finish().unwrap();
    out
}

#[test]
fn png16_identity_and_scaled() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (5u32, 4u32);
    let codes: Vec<u16> = (0..w * h).map(|i| (i * 3001 % 65536) as u16).collect();
    let data: Vec<u8> = codes.iter().flat_map(|c| c.to_be_bytes()).collect();
    let p = write(
        &dir,
        "h.png",
        &png_bytes(
            w,
            h,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &data,
        ),
    );

    let dem = read(&p).unwrap();
    assert_eq!((dem.width, dem.height), (5, 4));
    assert_eq!(dem.sample_type, SampleType::U16);
    assert!(
        dem.values
            .iter()
            .zip(&codes)
            .all(|(&v, &c)| v == f64::from(c))
    );

    let scaled = read_dem(
        &p,
        &opts(Some(Format::Png16 {
            scale: 0.1,
            offset: -100.0,
        })),
    )
    .unwrap();
    assert_eq!(scaled.sample_type, SampleType::F64);
    for (&v, &c) in scaled.values.iter().zip(&codes) {
        // The exactly-rounded decimal, e.g. 3001 -> 200.1, not 200.10000000000002.
        assert_eq!(v, (f64::from(c) - 1000.0) / 10.0);
    }
    assert_eq!(detect_quantum(&scaled), Some(0.1));

    let odd = read_dem(
        &p,
        &opts(Some(Format::Png16 {
            scale: 0.3,
            offset: 1.0,
        })),
    )
    .unwrap();
    assert_eq!(odd.values[1], 1.0 + 0.3 * f64::from(codes[1]));

    let e = read_dem(
        &p,
        &opts(Some(Format::Png16 {
            scale: 0.0,
            offset: 0.0,
        })),
    )
    .unwrap_err();
    assert!(matches!(e, CodecError::InvalidParameter(_)), "{e}");
}

#[test]
fn terrain_rgb_rgba_decodes_tenths() {
    let dir = TempDir::new().unwrap();
    // 100000 = 0 m; 100137 = 13.7 m; 0 = -10000 m; 0xFFFFFF = 1667721.5 m.
    let codes = [100_000u32, 100_137, 0, 0xFF_FFFF];
    let data: Vec<u8> = codes
        .iter()
        .flat_map(|&c| [(c >> 16) as u8, (c >> 8) as u8, c as u8, 255])
        .collect();
    let p = write(
        &dir,
        "t.png",
        &png_bytes(2, 2, png::ColorType::Rgba, png::BitDepth::Eight, &data),
    );
    let dem = read(&p).unwrap();
    assert_eq!(dem.values, vec![0.0, 13.7, -10000.0, 1_667_721.5]);
    assert_eq!(detect_quantum(&dem), Some(0.1));
}

#[test]
fn png_unsupported_layouts_and_truncation() {
    let dir = TempDir::new().unwrap();
    let gray8 = png_bytes(
        2,
        2,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
        &[1, 2, 3, 4],
    );
    let e = read(&write(&dir, "g8.png", &gray8)).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");
    assert!(e.to_string().contains("Grayscale at 8 bits"), "{e}");
    let e = read_dem(&dir.path().join("g8.png"), &opts(Some(Format::TerrainRgb))).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");

    let data: Vec<u8> = (0..64 * 64 * 2).map(|i| (i * 7 % 251) as u8).collect();
    let full = png_bytes(
        64,
        64,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
        &data,
    );
    let cut = &full[..full.len() / 2];
    let e = read(&write(&dir, "cut.png", cut)).unwrap_err();
    assert!(
        matches!(e, CodecError::Truncated(_) | CodecError::Corrupt(_)),
        "{e}"
    );

    let o = ReadOptions {
        limits: Limits {
            max_samples: 64 * 63,
        },
        ..ReadOptions::default()
    };
    let e = read_dem(&write(&dir, "full.png", &full), &o).unwrap_err();
    assert!(matches!(e, CodecError::LimitExceeded(_)), "{e}");
}

// ---------------------------------------------------------------------------------------------
// TIFF via the `tiff` encoder

fn tiff_with<C: colortype::ColorType>(
    compression: Compression,
    predictor: Predictor,
    w: u32,
    h: u32,
    data: &[C::Inner],
) -> Vec<u8>
where
    [C::Inner]: tiff::encoder::TiffValue,
{
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out)
        .unwrap()
        .with_compression(compression)
        .with_predictor(predictor);
    enc.write_image::<C>(w, h, data).unwrap();
    out.into_inner()
}

#[test]
fn tiff_integer_types_compressions_and_predictor() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (37u32, 23u32);
    let n = (w * h) as usize;
    let field = ramp(w as usize, h as usize);
    let want: Vec<f64> = field.iter().map(|&v| f64::from(v)).collect();

    let i16s: Vec<i16> = field.iter().map(|&v| v as i16).collect();
    for (name, comp, pred) in [
        ("lzw_h", Compression::Lzw, Predictor::Horizontal),
        (
            "deflate",
            Compression::Deflate(DeflateLevel::Fast),
            Predictor::None,
        ),
        ("packbits", Compression::Packbits, Predictor::None),
        ("none", Compression::Uncompressed, Predictor::Horizontal),
    ] {
        let bytes = tiff_with::<colortype::GrayI16>(comp, pred, w, h, &i16s);
        let dem = read(&write(&dir, &format!("{name}.tif"), &bytes)).unwrap();
        assert_eq!(
            (dem.width, dem.height, dem.sample_type),
            (37, 23, SampleType::I16)
        );
        assert_eq!(dem.values, want, "{name}");
        assert!(dem.georef.is_none() && dem.nodata.is_none());
    }

    let i32s: Vec<i32> = field.iter().map(|&v| v * 70_000).collect();
    let bytes = tiff_with::<colortype::GrayI32>(Compression::Lzw, Predictor::None, w, h, &i32s);
    let dem = read(&write(&dir, "i32.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::I32);
    assert_eq!(
        dem.values,
        i32s.iter().map(|&v| f64::from(v)).collect::<Vec<_>>()
    );
    // Every value is a multiple of 70000 and the field is not constant.
    assert_eq!(detect_quantum(&dem), Some(70_000.0));

    let u8s: Vec<u8> = (0..n).map(|i| (i % 256) as u8).collect();
    let bytes = tiff_with::<colortype::Gray8>(Compression::Packbits, Predictor::None, w, h, &u8s);
    let dem = read(&write(&dir, "u8.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::U8);
    assert_eq!(dem.values[300], f64::from(u8s[300]));

    let u32s: Vec<u32> = (0..n).map(|i| i as u32 * 100_003).collect();
    let bytes =
        tiff_with::<colortype::Gray32>(Compression::Uncompressed, Predictor::None, w, h, &u32s);
    let dem = read(&write(&dir, "u32.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::U32);
    assert_eq!(dem.values[n - 1], f64::from(u32s[n - 1]));

    let i8s: Vec<i8> = (0..n).map(|i| (i % 200) as i8).collect();
    let bytes =
        tiff_with::<colortype::GrayI8>(Compression::Uncompressed, Predictor::None, w, h, &i8s);
    let dem = read(&write(&dir, "i8.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::I8);
    assert_eq!(dem.values[150], -106.0);

    let u16s: Vec<u16> = (0..n).map(|i| (i * 50) as u16).collect();
    let bytes =
        tiff_with::<colortype::Gray16>(Compression::Lzw, Predictor::Horizontal, w, h, &u16s);
    let dem = read(&write(&dir, "u16.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::U16);
    assert_eq!(dem.values[n - 1], f64::from(u16s[n - 1]));
    assert_eq!(detect_quantum(&dem), Some(50.0));
}

#[test]
fn tiff_float64_and_bigtiff_float32() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (19u32, 11u32);
    let f64s: Vec<f64> = (0..w * h).map(|i| f64::from(i) * 0.01 - 1.0).collect();
    let bytes = tiff_with::<colortype::Gray64Float>(
        Compression::Deflate(DeflateLevel::Balanced),
        Predictor::None,
        w,
        h,
        &f64s,
    );
    let dem = read(&write(&dir, "f64.tif", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::F64);
    assert_eq!(dem.values, f64s);

    let f32s: Vec<f32> = (0..w * h).map(|i| (i as f32).sqrt() * 3.3).collect();
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new_big(&mut out)
        .unwrap()
        .with_compression(Compression::Lzw);
    enc.write_image::<colortype::Gray32Float>(w, h, &f32s)
        .unwrap();
    let bytes = out.into_inner();
    assert_eq!(&bytes[..4], b"II+\0", "the encoder wrote BigTIFF");
    // No extension: the BigTIFF magic must be enough.
    let dem = read(&write(&dir, "bigtiff_without_extension", &bytes)).unwrap();
    assert_eq!(dem.sample_type, SampleType::F32);
    assert!(
        dem.values
            .iter()
            .zip(&f32s)
            .all(|(&a, &b)| a == f64::from(b))
    );
    assert_eq!(detect_quantum(&dem), None);
}

#[test]
fn tiff_geokeys_and_gdal_nodata() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (4u32, 3u32);
    let data: Vec<f32> = vec![
        1.0, 2.0, -9999.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0,
    ];
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(w, h).unwrap();
    let d = img.encoder();
    d.write_tag(Tag::ModelPixelScaleTag, &[30.0f64, 25.0, 0.0][..])
        .unwrap();
    // Tiepoint at raster (1, 2) -> model (500030, 4000050): origin (500000, 4000100).
    d.write_tag(
        Tag::ModelTiepointTag,
        &[1.0f64, 2.0, 0.0, 500_030.0, 4_000_050.0, 0.0][..],
    )
    .unwrap();
    let keys: [u16; 16] = [
        1, 1, 0, 3, //
        1024, 0, 1, 1, // GTModelTypeGeoKey = projected
        1025, 0, 1, 2, // GTRasterTypeGeoKey = PixelIsPoint
        3072, 0, 1, 32633, // ProjectedCSTypeGeoKey = WGS 84 / UTM 33N
    ];
    d.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    d.write_tag(Tag::GdalNodata, "-9999").unwrap();
    img.write_data(&data).unwrap();
    let bytes = out.into_inner();

    let dem = read(&write(&dir, "geo.tif", &bytes)).unwrap();
    assert_eq!(dem.nodata, Some(-9999.0));
    assert!(!dem.is_valid(2) && dem.is_valid(3));
    let g = dem.georef.clone().unwrap();
    assert_eq!(g.epsg, Some(32633));
    assert_eq!((g.origin_x, g.origin_y), (500_000.0, 4_000_100.0));
    assert_eq!((g.pixel_x, g.pixel_y), (30.0, 25.0));
    assert!(!g.pixel_is_area);
}

/// A georeferenced float32 GeoTIFF whose VerticalUnitsGeoKey is `unit` (none when 0).
fn tiff_with_vertical_unit(unit: u16) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(2, 2).unwrap();
    let d = img.encoder();
    d.write_tag(Tag::ModelPixelScaleTag, &[10.0f64, 10.0, 0.0][..])
        .unwrap();
    d.write_tag(
        Tag::ModelTiepointTag,
        &[0.0f64, 0.0, 0.0, 1000.0, 2000.0, 0.0][..],
    )
    .unwrap();
    let mut keys: Vec<u16> = vec![1, 1, 0, 1, 3072, 0, 1, 32633];
    if unit != 0 {
        keys[3] = 2;
        keys.extend([4099, 0, 1, unit]); // VerticalUnitsGeoKey
    }
    d.write_tag(Tag::GeoKeyDirectoryTag, &keys[..]).unwrap();
    img.write_data(&[1.0f32, 2.0, 3.0, 4.0]).unwrap();
    out.into_inner()
}

#[test]
fn tiff_heights_in_feet_are_refused_naming_the_unit() {
    let dir = TempDir::new().unwrap();
    for unit in [0u16, 9001] {
        let path = write(
            &dir,
            &format!("unit{unit}.tif"),
            &tiff_with_vertical_unit(unit),
        );
        let dem = read(&path).unwrap_or_else(|e| panic!("unit {unit}: {e}"));
        assert_eq!(dem.values, [1.0, 2.0, 3.0, 4.0]);
        assert_eq!(dem.georef.unwrap().epsg, Some(32633));
    }
    for (unit, name) in [
        (9002u16, "(foot)"),
        (9003, "(US survey foot)"),
        (9036, "9036"),
    ] {
        let path = write(
            &dir,
            &format!("unit{unit}.tif"),
            &tiff_with_vertical_unit(unit),
        );
        let e = read(&path).unwrap_err();
        let msg = e.to_string();
        assert!(
            matches!(e, CodecError::Unsupported(_)),
            "unit {unit}: {e:?}"
        );
        assert!(
            msg.contains("VerticalUnitsGeoKey") && msg.contains(name) && msg.contains("metres"),
            "unit {unit}: {msg}"
        );
        // The streamed reader the builder uses for large files refuses it too.
        let Err(e) = cbdam_builder::input::GeoTiffSource::open(&path, None, &Limits::default())
        else {
            panic!("unit {unit}: the streamed reader accepted the file");
        };
        assert!(e.to_string().contains("VerticalUnitsGeoKey"), "{e}");
    }
}

#[test]
fn tiff_float32_lowest_nodata_written_by_gdal() {
    // GDAL writes f32::MIN as "-3.402823e+38", which parses to a double that is not f32::MIN.
    let dir = TempDir::new().unwrap();
    let data = [f32::MIN, 1.0, 2.5, f32::MIN];
    let mut out = Cursor::new(Vec::new());
    let mut enc = TiffEncoder::new(&mut out).unwrap();
    let mut img = enc.new_image::<colortype::Gray32Float>(2, 2).unwrap();
    img.encoder()
        .write_tag(Tag::GdalNodata, "-3.402823e+38")
        .unwrap();
    img.write_data(&data).unwrap();
    let dem = read(&write(&dir, "lowest.tif", &out.into_inner())).unwrap();
    assert_eq!(dem.nodata, Some(f64::from(f32::MIN)));
    assert_eq!(dem.valid_count(), 2);
    assert_eq!(detect_quantum(&dem), Some(0.5));
}

/// Finds IFD entry `tag` in a little-endian classic TIFF and overwrites its inline SHORT value,
/// to make files the encoder refuses to write.
fn patch_short_tag(bytes: &mut [u8], tag: u16, value: u16) {
    assert_eq!(&bytes[..4], b"II*\0");
    let ifd = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let count = u16::from_le_bytes([bytes[ifd], bytes[ifd + 1]]) as usize;
    for e in 0..count {
        let at = ifd + 2 + 12 * e;
        if u16::from_le_bytes([bytes[at], bytes[at + 1]]) == tag {
            bytes[at + 8..at + 10].copy_from_slice(&value.to_le_bytes());
            return;
        }
    }
    panic!("tag {tag} not in the IFD");
}

#[test]
fn tiff_unsupported_features_are_named() {
    let dir = TempDir::new().unwrap();
    let data: Vec<i16> = (0..64).collect();
    let mut bytes =
        tiff_with::<colortype::GrayI16>(Compression::Uncompressed, Predictor::None, 8, 8, &data);
    let good = read(&write(&dir, "good.tif", &bytes)).unwrap();
    assert_eq!(good.values[63], 63.0);

    patch_short_tag(&mut bytes, 259, 7);
    let e = read(&write(&dir, "jpeg.tif", &bytes)).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");
    assert!(
        e.to_string()
            .contains("TIFF compression JPEG (7) is not supported"),
        "{e}"
    );

    patch_short_tag(&mut bytes, 259, 50000);
    let e = read(&write(&dir, "zstd.tif", &bytes)).unwrap_err();
    assert!(e.to_string().contains("Zstandard (50000)"), "{e}");

    patch_short_tag(&mut bytes, 259, 1);
    patch_short_tag(&mut bytes, 317, 9);
    // No such predictor exists: the file is corrupt rather than using an unsupported feature.
    let e = read(&write(&dir, "pred.tif", &bytes)).unwrap_err();
    assert!(matches!(e, CodecError::Corrupt(_)), "{e}");
    assert!(e.to_string().contains("predictor “9”"), "{e}");

    let rgb: Vec<u8> = (0..8 * 8 * 3).map(|i| i as u8).collect();
    let bytes =
        tiff_with::<colortype::RGB8>(Compression::Uncompressed, Predictor::None, 8, 8, &rgb);
    let e = read(&write(&dir, "rgb.tif", &bytes)).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");
    assert!(e.to_string().contains("3 bands"), "{e}");

    let u64s: Vec<u64> = (0..64).collect();
    let bytes =
        tiff_with::<colortype::Gray64>(Compression::Uncompressed, Predictor::None, 8, 8, &u64s);
    let e = read(&write(&dir, "u64.tif", &bytes)).unwrap_err();
    assert!(matches!(e, CodecError::Unsupported(_)), "{e}");
    assert!(e.to_string().contains("64-bit unsigned integer"), "{e}");
}

#[test]
fn tiff_truncated_and_over_limit() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (64u32, 64u32);
    let data: Vec<i16> = ramp(64, 64).iter().map(|&v| v as i16).collect();
    let bytes =
        tiff_with::<colortype::GrayI16>(Compression::Uncompressed, Predictor::None, w, h, &data);
    // The encoder writes the IFD after the pixels, so a cut tail loses the directory itself.
    let e = read(&write(&dir, "cut_ifd.tif", &bytes[..bytes.len() - 20])).unwrap_err();
    assert!(
        matches!(e, CodecError::Truncated(_) | CodecError::Corrupt(_)),
        "{e}"
    );

    let o = ReadOptions {
        limits: Limits { max_samples: 4095 },
        ..ReadOptions::default()
    };
    let e = read_dem(&write(&dir, "full.tif", &bytes), &o).unwrap_err();
    assert!(matches!(e, CodecError::LimitExceeded(_)), "{e}");
    assert!(read_dem(&dir.path().join("full.tif"), &ReadOptions::default()).is_ok());
}

// ---------------------------------------------------------------------------------------------
// A hand-written TIFF: tiled, float32, floating-point predictor (TIFF Technical Note 3), with
// tiles overhanging the image, which the `tiff` encoder cannot produce.

struct Ifd(Vec<(u16, u16, u32, Vec<u8>)>);

impl Ifd {
    fn short(&mut self, tag: u16, v: u16) {
        self.0.push((tag, 3, 1, v.to_le_bytes().to_vec()));
    }
    fn longs(&mut self, tag: u16, v: &[u32]) {
        self.0.push((
            tag,
            4,
            v.len() as u32,
            v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        ));
    }
}

/// Predictor 3 for one row of f32: bytes split into planes, most significant first, then
/// byte-wise differences along the whole row.
fn fp_predict_row(row: &[f32]) -> Vec<u8> {
    let n = row.len();
    let mut planes = vec![0u8; 4 * n];
    for (i, v) in row.iter().enumerate() {
        for (k, b) in v.to_be_bytes().into_iter().enumerate() {
            planes[k * n + i] = b;
        }
    }
    let mut out = planes.clone();
    for j in 1..out.len() {
        out[j] = planes[j].wrapping_sub(planes[j - 1]);
    }
    out
}

/// A little-endian classic TIFF: header, tiles, out-of-line values, IFD.
fn tiled_fp_tiff(w: usize, h: usize, tw: usize, th: usize, field: &[f32]) -> Vec<u8> {
    let mut bytes = b"II*\0\0\0\0\0".to_vec();
    let (tx, ty) = (w.div_ceil(tw), h.div_ceil(th));
    let mut offsets = Vec::new();
    let mut counts = Vec::new();
    for tr in 0..ty {
        for tc in 0..tx {
            offsets.push(bytes.len() as u32);
            for r in 0..th {
                // Padding outside the image repeats a marker value the reader must drop.
                let row: Vec<f32> = (0..tw)
                    .map(|c| {
                        let (y, x) = (tr * th + r, tc * tw + c);
                        if x < w && y < h {
                            field[y * w + x]
                        } else {
                            -1.0e30
                        }
                    })
                    .collect();
                bytes.extend(fp_predict_row(&row));
            }
            counts.push((bytes.len() as u32) - offsets.last().unwrap());
        }
    }
    let mut ifd = Ifd(Vec::new());
    ifd.longs(256, &[w as u32]);
    ifd.longs(257, &[h as u32]);
    ifd.short(258, 32);
    ifd.short(259, 1);
    ifd.short(262, 1);
    ifd.short(277, 1);
    ifd.short(317, 3);
    ifd.longs(322, &[tw as u32]);
    ifd.longs(323, &[th as u32]);
    ifd.longs(324, &offsets);
    ifd.longs(325, &counts);
    ifd.short(339, 3);
    // Values over 4 bytes live outside the IFD.
    let mut entries = Vec::new();
    for (tag, ty, count, val) in &ifd.0 {
        let field = if val.len() <= 4 {
            let mut f = val.clone();
            f.resize(4, 0);
            f
        } else {
            let at = bytes.len() as u32;
            bytes.extend(val);
            at.to_le_bytes().to_vec()
        };
        entries.push((*tag, *ty, *count, field));
    }
    let ifd_at = bytes.len() as u32;
    bytes[4..8].copy_from_slice(&ifd_at.to_le_bytes());
    bytes.extend((entries.len() as u16).to_le_bytes());
    for (tag, ty, count, field) in entries {
        bytes.extend(tag.to_le_bytes());
        bytes.extend(ty.to_le_bytes());
        bytes.extend(count.to_le_bytes());
        bytes.extend(field);
    }
    bytes.extend(0u32.to_le_bytes());
    bytes
}

#[test]
fn tiff_tiled_float_predictor_with_padded_tiles() {
    let dir = TempDir::new().unwrap();
    let (w, h) = (37, 21);
    let field: Vec<f32> = (0..w * h)
        .map(|i| ((i * 7919) % 1000) as f32 * 0.37 - 120.5)
        .collect();
    let bytes = tiled_fp_tiff(w, h, 16, 16, &field);
    let dem = read(&write(&dir, "tiled_fp.tif", &bytes)).unwrap();
    assert_eq!(
        (dem.width, dem.height, dem.sample_type),
        (w, h, SampleType::F32)
    );
    for (i, (&got, &want)) in dem.values.iter().zip(&field).enumerate() {
        assert_eq!(
            got,
            f64::from(want),
            "sample {i} (row {}, col {})",
            i / w,
            i % w
        );
    }

    // A last tile that runs past the end of the file, as in an interrupted download with the
    // IFD written first, must read as truncated, not as garbage.
    let mut cut = bytes.clone();
    let ifd = u32::from_le_bytes(cut[4..8].try_into().unwrap()) as usize;
    let entries = u16::from_le_bytes([cut[ifd], cut[ifd + 1]]) as usize;
    let counts = (0..entries)
        .map(|e| ifd + 2 + 12 * e)
        .find(|&at| u16::from_le_bytes([cut[at], cut[at + 1]]) == 325)
        .unwrap();
    let tiles = u32::from_le_bytes(cut[counts + 4..counts + 8].try_into().unwrap()) as usize;
    let array = u32::from_le_bytes(cut[counts + 8..counts + 12].try_into().unwrap()) as usize;
    let last = array + 4 * (tiles - 1);
    cut[last..last + 4].copy_from_slice(&1_000_000u32.to_le_bytes());
    let e = read(&write(&dir, "tiled_cut.tif", &cut)).unwrap_err();
    assert!(matches!(e, CodecError::Truncated(_)), "{e}");
    assert!(e.to_string().contains("tile"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Format detection

#[test]
fn unknown_extension_without_magic_is_an_error() {
    let dir = TempDir::new().unwrap();
    let p = write(&dir, "dem.xyz", b"\x00\x01\x02\x03 not a dem");
    let e = read(&p).unwrap_err();
    assert!(matches!(e, CodecError::InvalidParameter(_)), "{e}");
    assert!(e.to_string().contains(".xyz"), "{e}");
    // Naming the format reads it regardless of the extension.
    let grid = write(
        &dir,
        "dem.txt",
        b"ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n7",
    );
    assert_eq!(read(&grid).unwrap().values, vec![7.0]);
    let e = read(&dir.path().join("missing.tif")).unwrap_err();
    assert!(matches!(e, CodecError::Io(_)), "{e}");
}

// ---------------------------------------------------------------------------------------------
// detect_quantum on grids built directly

fn dem(values: Vec<f64>, sample_type: SampleType, nodata: Option<f64>) -> Dem {
    Dem {
        width: values.len(),
        height: 1,
        values,
        sample_type,
        nodata,
        georef: None,
    }
}

#[test]
fn quantum_candidates_and_failures() {
    use SampleType::*;
    assert_eq!(detect_quantum(&dem(vec![], F32, None)), None);
    assert_eq!(
        detect_quantum(&dem(vec![f64::NAN, -9999.0], F32, Some(-9999.0))),
        None
    );
    assert_eq!(detect_quantum(&dem(vec![0.0; 10], F32, None)), Some(1.0));
    assert_eq!(detect_quantum(&dem(vec![100.0; 10], I16, None)), Some(1.0));
    assert_eq!(detect_quantum(&dem(vec![0.0; 10], I16, None)), Some(1.0));
    assert_eq!(
        detect_quantum(&dem(vec![10.0, -25.0, 5.0], I32, None)),
        Some(5.0)
    );
    assert_eq!(
        detect_quantum(&dem(vec![10.0, -25.0, 7.0], I32, None)),
        Some(1.0)
    );
    // Nodata and NaN are ignored.
    let d = dem(vec![1.5, f64::NAN, 0.123, -2.0], F64, Some(0.123));
    assert_eq!(detect_quantum(&d), Some(0.5));
    assert_eq!(
        detect_quantum(&dem(vec![0.2, 0.4, 1.0], F64, None)),
        Some(0.2)
    );
    let f32s = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
    assert_eq!(
        detect_quantum(&dem(f32s(&[0.05, 12.35, -7.1]), F32, None)),
        Some(0.05)
    );
    assert_eq!(
        detect_quantum(&dem(f32s(&[0.01, 123.45, 3.0]), F32, None)),
        Some(0.01)
    );
    // As f64 the same decimals also fit when exactly rounded ...
    assert_eq!(
        detect_quantum(&dem(vec![0.3, 1234.7], F64, None)),
        Some(0.1)
    );
    // ... but not an f32 value read as if it were an f64 decimal.
    assert_eq!(
        detect_quantum(&dem(vec![f64::from(0.3f32)], F64, None)),
        None
    );
    assert_eq!(detect_quantum(&dem(vec![0.001, 1.0], F64, None)), None);
    assert_eq!(
        detect_quantum(&dem(vec![1.0, f64::INFINITY], F64, None)),
        None
    );
    // Lidar-like floats.
    assert_eq!(
        detect_quantum(&dem(f32s(&[379.659_33, 380.0]), F32, None)),
        None
    );
}

#[test]
fn crop_takes_a_window_and_moves_the_georeferencing() {
    let dem = cbdam_codec::samples::Dem {
        width: 4,
        height: 3,
        values: (0..12).map(f64::from).collect(),
        sample_type: cbdam_codec::samples::SampleType::I16,
        nodata: None,
        georef: Some(cbdam_codec::repository::GeoRef {
            epsg: Some(4326),
            origin_x: 10.0,
            origin_y: 50.0,
            pixel_x: 0.5,
            pixel_y: 0.25,
            pixel_is_area: true,
            wkt: None,
        }),
    };
    let part = dem.crop(1, 1, 2, 2).unwrap();
    assert_eq!((part.width, part.height), (2, 2));
    assert_eq!(part.values, vec![5.0, 6.0, 9.0, 10.0]);
    let g = part.georef.unwrap();
    // One column east (+0.5) and one row south (−0.25, rows run north to south).
    assert_eq!((g.origin_x, g.origin_y, g.epsg), (10.5, 49.75, Some(4326)));
    for (x0, y0, w, h) in [
        (3, 0, 2, 1),
        (0, 2, 1, 2),
        (0, 0, 0, 1),
        (usize::MAX, 0, 2, 1),
    ] {
        assert!(dem.crop(x0, y0, w, h).is_err(), "{x0},{y0} {w}x{h}");
    }
}
