//! The mosaic's tests: placement, painting order, coarse-only points, shared edges and the
//! refusals, over small synthetic tiles.

use super::*;
use crate::input::ReadOptions;

/// Every value comes back bit for bit (a zero's sign aside) from the narrowest type chosen.
#[test]
fn samples_narrow_only_where_exact() {
    let cases: [(&[f64], &str); 5] = [
        (&[0.0, -32768.0, 32767.0, 1200.0], "i16"),
        (&[0.0, 32768.0, 1.5], "f32"),
        (&[f64::NAN, 7.0, -9999.0], "f32"),
        (&[0.1, 1.0], "f64"),
        // Beyond f32's range: f32 would make it infinite.
        (&[3.0e38 * 10.0, 1.0], "f64"),
    ];
    for (values, want) in cases {
        let s = Samples::compact(values.to_vec());
        let got = match &s {
            Samples::I16(_) => "i16",
            Samples::F32(_) => "f32",
            Samples::F64(_) => "f64",
        };
        assert_eq!(got, want, "{values:?}");
        for (i, &v) in values.iter().enumerate() {
            let back = s.get(i);
            assert!(
                back == v || (back.is_nan() && v.is_nan()),
                "{v} came back as {back}"
            );
        }
    }
    assert_eq!(Samples::compact(vec![1.0; 10]).bytes(), 20);
    assert_eq!(Samples::compact(vec![0.1; 10]).bytes(), 80);
}

/// The lattice the former in-memory mosaic built, point by point from the whole inputs:
/// winners (painting coarsest first, the last listed first, valid samples only), values and
/// resolution classes (coarse cells with four valid corners drawn from the coarse level).
fn reference(m: &Mosaic) -> (Vec<u32>, Vec<f64>, Vec<u8>) {
    let (w, h) = (m.width, m.height);
    let dems: Vec<_> = m
        .inputs
        .iter()
        .map(|p| {
            let opts = ReadOptions {
                nodata: p.nodata,
                ..ReadOptions::default()
            };
            crate::input::read_dem(&p.path, &opts).unwrap()
        })
        .collect();
    let mut winner = vec![NO_WINNER; w * h];
    let mut order: Vec<usize> = (0..m.inputs.len()).collect();
    order.sort_by_key(|&k| m.paint_key(k));
    for &k in &order {
        let (p, d) = (&m.inputs[k], &dems[k]);
        for r in 0..p.height {
            for c in 0..p.width {
                if d.is_valid(r * p.width + c) {
                    winner[(p.y0 + r * p.stride()) * w + p.x0 + c * p.stride()] = k as u32;
                }
            }
        }
    }
    let mut class: Vec<u8> = winner
        .iter()
        .map(|&k| match k {
            NO_WINNER => HOLE,
            k => m.inputs[k as usize].log2,
        })
        .collect();
    let values = (0..w * h)
        .map(|i| match winner[i] {
            NO_WINNER => f64::NAN,
            k => {
                let p = &m.inputs[k as usize];
                let (c, r) = ((i % w - p.x0) >> p.log2, (i / w - p.y0) >> p.log2);
                dems[k as usize].values[r * p.width + c]
            }
        })
        .collect();
    for (p, d) in m.inputs.iter().zip(&dems).filter(|(p, _)| p.log2 > 0) {
        let s = p.stride();
        for r in 0..p.height - 1 {
            for c in 0..p.width - 1 {
                let corners = [(c, r), (c + 1, r), (c, r + 1), (c + 1, r + 1)];
                if corners.iter().all(|&(c, r)| d.is_valid(r * p.width + c)) {
                    for y in p.y0 + r * s..=p.y0 + (r + 1) * s {
                        for x in p.x0 + c * s..=p.x0 + (c + 1) * s {
                            if class[y * w + x] == HOLE {
                                class[y * w + x] = COARSE_ONLY;
                            }
                        }
                    }
                }
            }
        }
    }
    (winner, values, class)
}

/// Inputs at strides 1, 2 and 4 that overlap (agreeing where they share a spacing), with
/// nodata that falls through to coarser inputs: every block size, down to one row a block
/// and under a cache that keeps nothing, composes the lattice the whole inputs make.
#[test]
fn blocks_of_any_size_compose_the_whole_inputs_lattice() {
    use crate::write::{Raster, write_geotiff};
    let dir = tempfile::tempdir().unwrap();
    const ND: f64 = -9999.0;
    // (name, lattice column and row of the first sample, stride, columns, rows)
    let inputs = [
        ("fine_a", 5, 7, 1, 30, 25),
        ("coarse", 0, 0, 4, 20, 15),
        ("fine_b", 21, 19, 1, 20, 22),
        ("medium", 2, 30, 2, 16, 12),
    ];
    let mut paths = Vec::new();
    for (name, x0, y0, s, w, h) in inputs {
        let values = (0..w * h)
            .map(|i| {
                let (x, y) = (x0 + (i % w) * s, y0 + (i / w) * s);
                // Holes: a block in `fine_a` (where `fine_b` and `coarse` show through), a
                // coarse sample, a diagonal of `medium`.
                let hole = match name {
                    "fine_a" => (22..27).contains(&x) && (20..30).contains(&y),
                    "coarse" => (x, y) == (40, 20),
                    _ => name == "medium" && i % (w + 1) == 3,
                };
                if hole {
                    ND
                } else {
                    // One function of the lattice point per stride: inputs of one spacing
                    // agree where they overlap.
                    ((x * 7 + y * 13) % 50) as f64 + 100.0 * s as f64
                }
            })
            .collect();
        let r = Raster {
            width: w,
            height: h,
            values,
            georef: Some(GeoRef {
                epsg: Some(32632),
                origin_x: 500_000.0 + x0 as f64 * 10.0,
                origin_y: 4_000_000.0 - y0 as f64 * 10.0,
                pixel_x: 10.0 * s as f64,
                pixel_y: 10.0 * s as f64,
                pixel_is_area: false,
                wkt: None,
            }),
        };
        let path = dir.path().join(format!("{name}.tif"));
        write_geotiff(std::fs::File::create(&path).unwrap(), &r, Some(ND), false).unwrap();
        paths.push(path);
    }
    let mut m = mosaic(&paths, &ReadOptions::default(), 1 << 30).unwrap();
    assert_eq!((m.width, m.height), (77, 57));
    let (winner, values, class) = reference(&m);
    assert!(class.contains(&COARSE_ONLY) && class.contains(&HOLE) && class.contains(&1));
    let same = |a: &[f64], b: &[f64]| {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
    };
    for (points, budget) in [(BLOCK_POINTS, 1 << 30), (1, 0), (3 * 77 + 5, 4096)] {
        m.block_points = points;
        m.cache = BandCache::new(budget);
        let survey = m.survey().unwrap();
        assert!(
            survey.resolution.class[..] == class[..],
            "classes, blocks of {points}"
        );
        let valid: Vec<f64> = values.iter().copied().filter(|v| !v.is_nan()).collect();
        let lo = valid.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = valid.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        assert_eq!(survey.range, (lo, hi));
        let (mut got_w, mut got_v) = (Vec::new(), Vec::new());
        m.for_each_block_winners(&mut |y0, v, w| {
            assert_eq!(y0 * m.width, got_v.len());
            got_v.extend_from_slice(v);
            got_w.extend_from_slice(w);
            Ok(())
        })
        .unwrap();
        assert!(got_w == winner, "winners, blocks of {points}");
        assert!(same(&got_v, &values), "values, blocks of {points}");
        let mut streamed = Vec::new();
        m.for_each_block(&mut |_, v| {
            streamed.extend_from_slice(v);
            Ok(())
        })
        .unwrap();
        assert!(same(&streamed, &values), "source, blocks of {points}");
    }
    // A sample of `fine_b` changed where it overlaps `fine_a`: refused, naming both.
    let mut b = crate::input::read_dem(&paths[2], &ReadOptions::default()).unwrap();
    b.values[0] += 2.5;
    let r = Raster {
        width: b.width,
        height: b.height,
        values: b.values,
        georef: b.georef,
    };
    write_geotiff(
        std::fs::File::create(&paths[2]).unwrap(),
        &r,
        Some(ND),
        false,
    )
    .unwrap();
    let e = mosaic(&paths, &ReadOptions::default(), 1 << 30)
        .unwrap()
        .survey()
        .err()
        .expect("disagreeing tiles accepted")
        .to_string();
    assert!(
        e.contains("fine_b.tif")
            && e.contains("fine_a.tif")
            && e.contains("disagree on 1 of their")
            && e.contains("by up to 2.5"),
        "{e}"
    );
}
