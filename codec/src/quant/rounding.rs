//! The float rounding a plan's arithmetic can add to its bound, from the plan alone.
//!
//! A sample `v` is mapped to an integer `n = round((v − offset)/unit)` and reconstructed as
//! `fl(offset + fl(n·unit))`. In exact arithmetic the error is at most `k·unit` plus the
//! pre-quantization (`unit/2`, or the lattice's representation error); in `f64` each step can
//! round. [`QuantPlan::rounding_error`] bounds what those roundings add, for every height the
//! format can hold (`|n| ≤ MAX_ABS_HEIGHT`), so that every reader derives the same guarantee
//! from the header without knowing the data's range.
//!
//! It is 0 when the arithmetic is exact: lattice data with no representation error on a unit
//! that is a power of two (whole metres, half metres, colour levels) and an offset that is a
//! multiple of it. Then `v − offset`, the division, `n·unit` and the sum are all exact binary
//! numbers of fewer than 53 bits. Otherwise (a decimal unit such as 0.001 m, float input) it is
//! `2⁻⁴⁹·(MAX_ABS_HEIGHT·unit + |offset| + unit)`, which covers, with `A = MAX_ABS_HEIGHT·unit`
//! the largest `|n·unit|` and `U = 2⁻⁵³` the unit roundoff:
//! - the reconstruction of the input's and of the decoded integer, `2·U·(2A + |offset|)`;
//! - float input's pre-quantization, `fl(v − offset)` and the rounding to an integer,
//!   `≤ 2·U·A` beyond `unit/2`;
//! - the subtraction that measures an error and the sums that state the bound, `≤ 4·U·A`;
//!
//! in all at most `12·U·A + 2·U·|offset| < 16·U·(A + |offset| + unit)`, plus the smallest
//! normal number for products that underflow.

use super::QuantPlan;
use crate::lifting::MAX_ABS_HEIGHT;

/// `2⁻⁴⁹`: sixteen times the unit roundoff of `f64`.
const ROUNDING_FACTOR: f64 = 1.0 / (1u64 << 49) as f64;

impl QuantPlan {
    /// Whether mapping samples to integers and back is exact in `f64` (see the module's
    /// comment): lattice data with no representation error, a unit that is a power of two and
    /// an offset that is a multiple of it, all heights within 53 bits.
    pub fn is_exact(&self) -> bool {
        let mantissa = self.unit.to_bits() & ((1u64 << 52) - 1);
        let binary_unit = self.unit.is_normal() && self.unit > 0.0 && mantissa == 0;
        let offset_units = self.offset / self.unit;
        self.lattice
            && self.representation_error == 0.0
            && binary_unit
            && offset_units.fract() == 0.0
            && offset_units.abs() + f64::from(MAX_ABS_HEIGHT) <= (1u64 << 53) as f64
    }

    /// A bound, metres, on what float rounding adds to the error between a sample and its
    /// reconstruction beyond [`QuantPlan::quantization_error`]: 0 where the arithmetic is exact
    /// ([`QuantPlan::is_exact`]), else `2⁻⁴⁹·(MAX_ABS_HEIGHT·unit + |offset| + unit)` (the
    /// module's comment derives it).
    pub fn rounding_error(&self) -> f64 {
        if self.is_exact() {
            return 0.0;
        }
        let reach = f64::from(MAX_ABS_HEIGHT) * self.unit;
        ROUNDING_FACTOR * (reach + self.offset.abs() + self.unit) + f64::MIN_POSITIVE
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn whole_metres_and_binary_lattices_are_exact() {
        let p = QuantPlan::new(1.0, Some(1.0), 1111.0, 3270.0).unwrap();
        assert!(p.is_exact() && p.rounding_error() == 0.0, "{p:?}");
        assert_eq!(p.max_error(), p.quantization_error());
        let p = QuantPlan::new(2.0, Some(0.5), -8000.0, 8000.0).unwrap();
        assert!(p.is_exact(), "{p:?}");
    }

    #[test]
    fn decimal_units_and_float_input_state_a_rounding_term() {
        let decimal = QuantPlan::new(0.001, Some(0.001), -8000.0, 8000.0).unwrap();
        let float = QuantPlan::new(1.0, None, -8000.0, 8000.0).unwrap();
        for p in [decimal, float] {
            let r = p.rounding_error();
            assert!(!p.is_exact() && r > 0.0 && r < p.unit * 1e-6, "{p:?}: {r}");
            assert!(p.max_error() > p.quantization_error() + r * 0.999, "{p:?}");
        }
    }

    /// Every reconstruction within `k` units of a sample on a decimal lattice (whole metres
    /// from −8000 to 8000, which every decimal quantum holds exactly) stays within the stated
    /// bound, measured in `f64` as `verify` measures it. Before the rounding term, 0.001 m
    /// data broke its 0.001 m bound by 2e-13 m.
    #[test]
    fn the_stated_bound_covers_reconstruction_at_large_heights() {
        use crate::samples::{Dem, SampleType};
        for q in [0.001, 0.01, 0.05, 0.1, 0.2] {
            let values: Vec<f64> = (-8000..=8000).map(f64::from).collect();
            let dem = Dem {
                width: values.len(),
                height: 1,
                values,
                sample_type: SampleType::F64,
                nodata: None,
                georef: None,
            };
            let p = QuantPlan::for_dem(&dem, q, Some(q)).unwrap();
            let k = p.quantizer.k();
            let mut worst = 0f64;
            for &v in &dem.values {
                let n = p.to_units(v).unwrap().unwrap();
                for d in -k..=k {
                    worst = worst.max((p.metres(n + d) - v).abs());
                }
            }
            assert!(
                p.representation_error == 0.0 && worst > p.quantization_error(),
                "quantum {q}: rounding never showed ({worst}, {p:?})"
            );
            assert!(
                worst <= p.max_error(),
                "quantum {q}: {worst} > {}",
                p.max_error()
            );
        }
    }

    #[test]
    fn the_bound_text_rounds_the_rounding_term_up() {
        let p = QuantPlan::new(0.001, Some(0.001), -8000.0, 8000.0).unwrap();
        let text = p.bound_text();
        let r: f64 = text
            .split(" m + ")
            .nth(1)
            .and_then(|t| t.strip_suffix(" m of float rounding"))
            .and_then(|t| t.parse().ok())
            .unwrap_or_else(|| panic!("{text}"));
        assert!(
            r >= p.rounding_error() && r <= p.rounding_error() * 1.1,
            "{text}"
        );
        assert!(text.starts_with("0.001 m + "), "{text}");
        let whole = QuantPlan::new(1.0, Some(1.0), 0.0, 10.0).unwrap();
        assert_eq!(whole.bound_text(), "1 m");
    }
}
