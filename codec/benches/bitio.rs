//! Bit reader vs `bitvec`, and Elias-gamma record decode throughput.
//!
//! `cargo bench -p cbdam-codec --bench bitio -- --warm-up-time 1 --measurement-time 3`

use std::hint::black_box;

use bitvec::field::BitField;
use bitvec::prelude::{BitSlice, Msb0};
use cbdam_codec::entropy::bitio::{BitReader, BitWriter};
use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, decode_bands, encode_bands,
};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// xorshift64*: deterministic, dependency-free.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Laplacian with the given scale, rounded to an integer.
    fn laplace(&mut self, scale: f64) -> i32 {
        let u = self.unit() - 0.5;
        let mag = -scale * (1.0 - 2.0 * u.abs()).max(1e-300).ln();
        (mag.round() as i32) * if u < 0.0 { -1 } else { 1 }
    }
}

const N_CODES: usize = 1 << 16;

fn bench_readers(c: &mut Criterion) {
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);

    // Raw fields of random widths 1..=32.
    let fields: Vec<(u32, u32)> = (0..N_CODES)
        .map(|_| {
            let n = (rng.next() % 32) as u32 + 1;
            let v = (rng.next() as u32) >> (32 - n);
            (n, v)
        })
        .collect();
    let mut w = BitWriter::new();
    for &(n, v) in &fields {
        w.put_bits(v, n);
    }
    let raw = w.finish();
    let widths: Vec<u32> = fields.iter().map(|f| f.0).collect();

    // Gamma codes of Laplacian-ish magnitudes (mostly 1..4).
    let gammas: Vec<u32> = (0..N_CODES)
        .map(|_| rng.laplace(2.0).unsigned_abs() + 1)
        .collect();
    let mut w = BitWriter::new();
    for &g in &gammas {
        w.put_gamma(g);
    }
    let gam = w.finish();

    let mut g = c.benchmark_group("bitreader");
    g.throughput(Throughput::Elements(N_CODES as u64));

    g.bench_function("raw_bits/ours", |b| {
        b.iter(|| {
            let mut r = BitReader::new(black_box(&raw));
            let mut acc = 0u32;
            for &n in &widths {
                acc = acc.wrapping_add(r.get_bits(n));
            }
            acc
        })
    });
    g.bench_function("raw_bits/bitvec", |b| {
        b.iter(|| {
            let bits = BitSlice::<u8, Msb0>::from_slice(black_box(&raw));
            let mut pos = 0usize;
            let mut acc = 0u32;
            for &n in &widths {
                let n = n as usize;
                acc = acc.wrapping_add(bits[pos..pos + n].load_be::<u32>());
                pos += n;
            }
            acc
        })
    });
    g.bench_function("gamma/ours", |b| {
        b.iter(|| {
            let mut r = BitReader::new(black_box(&gam));
            let mut acc = 0u32;
            for _ in 0..N_CODES {
                acc = acc.wrapping_add(r.get_gamma(31).unwrap_or(0));
            }
            acc
        })
    });
    g.bench_function("gamma/bitvec", |b| {
        b.iter(|| {
            let bits = BitSlice::<u8, Msb0>::from_slice(black_box(&gam));
            let mut pos = 0usize;
            let mut acc = 0u32;
            for _ in 0..N_CODES {
                let k = bits[pos..].first_one().unwrap_or(0);
                let v: u32 = bits[pos + k..pos + 2 * k + 1].load_be();
                pos += 2 * k + 1;
                acc = acc.wrapping_add(v);
            }
            acc
        })
    });
    g.finish();
}

/// `(label, probability of non-zero, Laplacian scale of the non-zeros)`.
const DENSITIES: [(&str, f64, f64); 4] = [
    ("sparse_5pct_pm1-3", 0.05, 0.8),
    ("half_pm1-3", 0.5, 0.8),
    ("dense_pm1-3", 1.0, 0.8),
    ("dense_large_scale200", 1.0, 200.0),
];

fn band_values(rng: &mut Rng, n: usize, p: f64, scale: f64) -> Vec<i32> {
    (0..n)
        .map(|_| {
            if rng.unit() >= p {
                return 0;
            }
            let v = rng.laplace(scale);
            if v == 0 {
                if rng.next() & 1 == 0 { 1 } else { -1 }
            } else {
                v
            }
        })
        .collect()
}

fn bench_decode(c: &mut Criterion) {
    let mut rng = Rng(0xC0DE_C0DE_C0DE_C0DE);
    let mut g = c.benchmark_group("gamma_decode");
    for (side, kind) in [(64usize, BandKind::Cells), (63, BandKind::Vertices)] {
        g.throughput(Throughput::Elements((side * side) as u64));
        for (label, p, scale) in DENSITIES {
            let vals = band_values(&mut rng, side * side, p, scale);
            let mut rec = Vec::new();
            encode_bands(
                CoderKind::EliasGamma,
                &[Band {
                    kind,
                    width: side,
                    height: side,
                    values: &vals,
                }],
                &mut rec,
            );
            let mut out = vec![0i32; side * side];
            let name = format!(
                "{side}x{side}/{label}/{:.2}bps",
                rec.len() as f64 * 8.0 / vals.len() as f64
            );
            g.bench_function(name, |b| {
                b.iter(|| {
                    let mut bands = [BandMut {
                        kind,
                        width: side,
                        height: side,
                        values: &mut out,
                    }];
                    decode_bands(
                        CoderKind::EliasGamma,
                        black_box(&rec),
                        &mut bands,
                        DecodeLimits::default(),
                    )
                    .expect("valid record");
                })
            });
            assert_eq!(out, vals);
        }
    }
    g.finish();

    let mut g = c.benchmark_group("gamma_encode");
    g.throughput(Throughput::Elements(64 * 64));
    let vals = band_values(&mut rng, 64 * 64, 0.5, 0.8);
    let mut rec = Vec::new();
    g.bench_function("64x64/half_pm1-3", |b| {
        b.iter(|| {
            rec.clear();
            encode_bands(
                CoderKind::EliasGamma,
                &[Band {
                    kind: BandKind::Cells,
                    width: 64,
                    height: 64,
                    values: black_box(&vals),
                }],
                &mut rec,
            );
        })
    });
    g.finish();
}

criterion_group!(benches, bench_readers, bench_decode);
criterion_main!(benches);
