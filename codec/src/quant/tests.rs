//! Tests of the quantizer and of quantization plans.

use super::MAX_K;
use super::quantizer::FAST_INDEX_RANGE;
use super::{HeightGrid, QuantPlan, Quantizer};

proptest::proptest! {
    #[test]
    fn quantizer_index_is_floor_division(
        k in proptest::prop_oneof![0i32..300, 0..=MAX_K],
        r in proptest::prop_oneof![-3000i64..3000, -(3i64 << 30)..(3i64 << 30), i64::from(i32::MIN)..=i64::from(i32::MAX)],
    ) {
        let q = Quantizer::new(k as u32).unwrap();
        let step = i64::from(q.step());
        proptest::prop_assert_eq!(q.index(r), (r + i64::from(k)).div_euclid(step));
    }
}

#[test]
fn quantizer_index_is_exact_at_the_ends_of_the_fast_range() {
    for k in [0, 1, 2, 3, 1000, 65535, MAX_K - 1, MAX_K] {
        let q = Quantizer::new(k as u32).unwrap();
        let step = i64::from(q.step());
        for centre in [0, FAST_INDEX_RANGE, -FAST_INDEX_RANGE] {
            for x in centre - 2 * step - 2..=centre + 2 * step + 2 {
                let r = x - i64::from(k);
                assert_eq!(q.index(r), x.div_euclid(step), "k {k}, r {r}");
            }
        }
    }
}

#[test]
fn quantizer_error_is_bounded_for_negative_residuals_too() {
    for k in [0u32, 1, 2, 7, 100] {
        let q = Quantizer::new(k).unwrap();
        for r in -1000i64..=1000 {
            let idx = q.index(r);
            let err = r - idx * i64::from(q.step());
            assert!(err.abs() <= i64::from(k), "k={k} r={r} idx={idx}");
        }
    }
}

#[test]
fn plans_use_the_quantum_or_a_binary_unit() {
    let p = QuantPlan::new(1.0, Some(1.0), 1111.0, 3270.0).unwrap();
    assert_eq!((p.unit, p.quantizer.k(), p.lattice), (1.0, 1, true));
    assert_eq!(p.offset, 2191.0, "mid-range 2190.5 rounded to the lattice");
    let p = QuantPlan::new(0.4, Some(1.0), 0.0, 10.0).unwrap();
    assert_eq!(p.quantizer.k(), 0, "ε < u stores lattice data losslessly");
    let p = QuantPlan::new(0.3, Some(0.1), 13.7, 3751.0).unwrap();
    assert_eq!(p.quantizer.k(), 3, "0.3 m on 0.1 m data is three steps");
    let p = QuantPlan::new(1.0, None, 379.6, 410.8).unwrap();
    assert_eq!((p.unit, p.quantizer.k()), (0.125, 7));
    assert!(p.max_error() <= 1.0);
    for eps in [0.0025, 0.01, 0.1, 0.3, 0.5, 1.0, 2.0, 5.0, 100.0] {
        let p = QuantPlan::new(eps, None, -11000.0, 9000.0).unwrap();
        // Within ε in exact arithmetic; the stated bound adds the float rounding term.
        let stated = (p.quantization_error() + p.rounding_error()).next_up();
        assert!(
            p.quantization_error() <= eps && p.max_error() <= stated,
            "{eps}: {p:?}"
        );
        assert!(p.quantizer.k() >= 7, "{eps}: {p:?}");
        if eps > 0.003 {
            assert_eq!(p.unit.log2().fract(), 0.0, "unit is a power of two");
        }
    }
}

#[test]
fn impossible_tolerances_are_refused_with_a_reason() {
    for eps in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(QuantPlan::new(eps, None, 0.0, 1.0).is_err());
    }
    let err = QuantPlan::new(1e-4, None, -11000.0, 9000.0)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("too fine") && err.contains("smallest"),
        "{err}"
    );
    assert!(QuantPlan::new(1.0, Some(0.0), 0.0, 1.0).is_err());
    assert!(QuantPlan::new(1.0, None, f64::NAN, 1.0).is_err());
}

#[test]
fn awkward_floats_are_handled_deliberately() {
    let p = QuantPlan::new(0.01, None, 0.0, 100.0).unwrap();
    assert_eq!(p.to_units(f64::NAN).unwrap(), None);
    assert!(p.to_units(f64::INFINITY).is_err());
    assert!(p.to_units(f64::NEG_INFINITY).is_err());
    assert!(p.to_units(1e30).is_err());
    assert!(p.to_units(-1e30).is_err());
    // Values below the unit (3e-12 next to 100, subnormals) pre-quantize within budget.
    for v in [3e-12, f64::from(f32::from_bits(1)), -0.0, 100.0 - 3e-12] {
        let n = p.to_units(v).unwrap().unwrap();
        assert!((p.metres(n) - v).abs() <= p.unit / 2.0, "{v}");
    }
    // A quantum override the data does not honour is caught, not silently rounded.
    let p = QuantPlan::new(1.0, Some(1.0), 0.0, 100.0).unwrap();
    assert!(p.to_units(12.5).is_err());
    assert_eq!(p.to_units(12.0).unwrap(), Some(12 - 50));
    let err = HeightGrid::from_metres(2, 1, &[1.0, f64::INFINITY], None, &p).unwrap_err();
    // Decimal data stored as float32 is off its lattice by up to half an ulp: that comes
    // out of the budget, so 0.5 m on 0.1 m data stored as f32 takes 4 steps, not 5.
    let v = f64::from(3751.3f32);
    let dev = (v - 3751.3).abs();
    assert!(dev > 0.0);
    let p = QuantPlan::with_representation_error(0.5, Some(0.1), dev, 13.7, 3751.3).unwrap();
    assert_eq!(p.quantizer.k(), 4);
    assert!(p.max_error() <= 0.5);
    assert_eq!(
        QuantPlan::new(0.5, Some(0.1), 13.7, 3751.3)
            .unwrap()
            .quantizer
            .k(),
        5
    );
    assert!(QuantPlan::with_representation_error(dev / 2.0, Some(0.1), dev, 0.0, 1.0).is_err());
    assert!(err.to_string().contains("column 1, row 0"), "{err}");
}
