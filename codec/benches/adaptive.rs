//! Encode and decode throughput of the adaptive coder on 64×64 bands of several densities.

use cbdam_codec::entropy::{
    Band, BandKind, BandMut, CoderKind, DecodeLimits, decode_bands, encode_bands,
};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;

const N: usize = 64;
/// Bands per iteration, so per-record setup is measured in proportion.
const BANDS: usize = 64;

/// SplitMix64, so the data are the same on every run.
struct Rng(u64);
impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    /// Rounded Laplacian sample.
    fn laplace(&mut self, scale: f64) -> i32 {
        let v = (-scale * self.unit().ln()).round() as i32;
        if self.unit() < 0.5 { v } else { -v }
    }
}

/// `BANDS` bands where each sample is a Laplacian draw with probability `density`, else zero.
fn bands(scale: f64, density: f64) -> Vec<Vec<i32>> {
    let mut rng = Rng(1);
    (0..BANDS)
        .map(|_| {
            (0..N * N)
                .map(|_| {
                    if rng.unit() < density {
                        rng.laplace(scale)
                    } else {
                        0
                    }
                })
                .collect()
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let cases: [(&str, f64, f64); 4] = [
        ("all_zero", 0.0, 0.0),
        ("mostly_zero", 1.0, 0.02),
        ("laplace_1", 1.0, 1.0),
        ("laplace_8", 8.0, 1.0),
    ];
    let mut g = c.benchmark_group("adaptive");
    g.throughput(Throughput::Elements((BANDS * N * N) as u64));
    for (name, scale, density) in cases {
        let data = bands(scale, density);
        let records: Vec<Vec<u8>> = data
            .iter()
            .map(|v| {
                let mut out = Vec::new();
                let band = Band {
                    kind: BandKind::Cells,
                    width: N,
                    height: N,
                    values: v,
                };
                encode_bands(CoderKind::Adaptive, &[band], &mut out);
                out
            })
            .collect();
        let bytes: usize = records.iter().map(Vec::len).sum();
        let nonzero = data.iter().flatten().filter(|&&v| v != 0).count();
        eprintln!(
            "{name}: {:.3} bits/sample, {:.1}% non-zero",
            bytes as f64 * 8.0 / (BANDS * N * N) as f64,
            100.0 * nonzero as f64 / (BANDS * N * N) as f64
        );
        g.bench_function(format!("encode/{name}"), |b| {
            let mut out = Vec::new();
            b.iter(|| {
                out.clear();
                for v in &data {
                    let band = Band {
                        kind: BandKind::Cells,
                        width: N,
                        height: N,
                        values: v,
                    };
                    encode_bands(CoderKind::Adaptive, &[band], &mut out);
                }
                black_box(out.len())
            })
        });
        g.bench_function(format!("decode/{name}"), |b| {
            let mut buf = vec![0i32; N * N];
            b.iter(|| {
                for r in &records {
                    let mut band = [BandMut {
                        kind: BandKind::Cells,
                        width: N,
                        height: N,
                        values: &mut buf,
                    }];
                    decode_bands(CoderKind::Adaptive, r, &mut band, DecodeLimits::default())
                        .unwrap();
                }
                black_box(buf[0])
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
