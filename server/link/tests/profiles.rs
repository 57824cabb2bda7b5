//! The named profiles and the validation of parameters.

use std::time::Duration;

use cbdam_link::Link;

#[test]
fn profiles_parse_by_name_with_their_documented_figures() {
    let l: Link = "adsl".parse().unwrap();
    assert_eq!((l.down_bps, l.up_bps), (1_200_000, 256_000));
    assert_eq!(l.delay * 2, Duration::from_millis(60));
    let l: Link = "DSL10".parse().unwrap();
    assert_eq!(
        (l.down_bps, l.delay * 2),
        (10_000_000, Duration::from_millis(50))
    );
    let l: Link = "fiber".parse().unwrap();
    assert_eq!(l, Link::FIBRE);
    assert_eq!(
        (l.down_bps, l.delay * 2),
        (100_000_000, Duration::from_millis(20))
    );
    let l: Link = " mobile ".parse().unwrap();
    assert_eq!(
        (l.down_bps, l.delay * 2),
        (5_000_000, Duration::from_millis(120))
    );
    assert_eq!(l.reset_prob, 0.01);
    for (_, l) in Link::PROFILES {
        l.validate().unwrap();
    }
    let e = "isdn".parse::<Link>().unwrap_err();
    assert!(e.contains("\"isdn\"") && e.contains("dsl10"), "{e}");
    assert_eq!(
        Link::ADSL.to_string(),
        "1.2 Mbit/s down, 256 kbit/s up, 30 ms each way (60 ms round trip)"
    );
    assert!(Link::MOBILE.to_string().contains("1% of connections reset"));
}

#[test]
fn bad_parameters_are_refused_by_name() {
    let bad = |l: Link, word: &str| {
        let e = l.validate().unwrap_err();
        assert!(e.contains(word), "{e}");
    };
    bad(Link::custom(999, 1_000_000, Duration::ZERO), "downstream");
    bad(Link::custom(1_000_000, 0, Duration::ZERO), "upstream");
    bad(Link::custom(1000, 1000, Duration::from_secs(61)), "delay");
    bad(
        Link {
            jitter: Duration::from_secs(100),
            ..Link::FIBRE
        },
        "jitter",
    );
    for p in [-0.1, 1.5, f64::NAN] {
        bad(
            Link {
                reset_prob: p,
                ..Link::FIBRE
            },
            "reset probability",
        );
    }
    // Bursts: 10 ms of the rate, within one packet and 16 KiB.
    assert_eq!(Link::burst(1_200_000), 1500);
    assert_eq!(Link::burst(10_000_000), 12_500);
    assert_eq!(Link::burst(100_000_000), 16 * 1024);
}
