//! Single byte-range requests (RFC 9110 §14): `bytes=a-b`, `bytes=a-`, `bytes=-n`.

use std::ops::Range;

/// What a `Range` header asks of a resource of known length.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RangeRequest {
    /// Serve the whole resource with 200: no header, a header we ignore as RFC 9110 allows
    /// (syntactically invalid, another unit, or several ranges — clients of this server ask for
    /// one range at a time, and a multipart body would have to be assembled just for them).
    Full,
    /// Serve these bytes with 206.
    Partial(Range<u64>),
    /// Nothing satisfiable: 416 with `Content-Range: bytes */len`.
    Unsatisfiable,
}

/// Interprets `header` (the `Range` value, if any) for a resource of `len` bytes.
pub fn parse_range(header: Option<&str>, len: u64) -> RangeRequest {
    let Some(h) = header else {
        return RangeRequest::Full;
    };
    let Some(spec) = h.trim().strip_prefix("bytes=") else {
        return RangeRequest::Full;
    };
    if spec.contains(',') {
        return RangeRequest::Full;
    }
    let Some((a, b)) = spec.trim().split_once('-') else {
        return RangeRequest::Full;
    };
    let num = |t: &str| -> Option<u64> {
        // `u64::from_str` takes a leading '+', which the grammar does not.
        (!t.is_empty() && t.bytes().all(|c| c.is_ascii_digit()))
            .then(|| t.parse().ok())
            .flatten()
    };
    match (a.trim(), b.trim()) {
        ("", n) => match num(n) {
            None => RangeRequest::Full,
            // A suffix of length 0 selects nothing; an empty resource has no suffix either.
            Some(0) => RangeRequest::Unsatisfiable,
            Some(_) if len == 0 => RangeRequest::Unsatisfiable,
            Some(n) => RangeRequest::Partial(len.saturating_sub(n)..len),
        },
        (a, "") => match num(a) {
            None => RangeRequest::Full,
            Some(a) if a >= len => RangeRequest::Unsatisfiable,
            Some(a) => RangeRequest::Partial(a..len),
        },
        (a, b) => match (num(a), num(b)) {
            (Some(a), Some(b)) if a <= b => {
                if a >= len {
                    RangeRequest::Unsatisfiable
                } else {
                    RangeRequest::Partial(a..b.min(len - 1) + 1)
                }
            }
            // last < first is invalid syntax, which is ignored, not refused.
            _ => RangeRequest::Full,
        },
    }
}

#[cfg(test)]
mod tests {
    use super::RangeRequest::*;
    use super::*;

    #[test]
    fn the_three_forms() {
        assert_eq!(parse_range(Some("bytes=0-9"), 100), Partial(0..10));
        assert_eq!(parse_range(Some("bytes=90-200"), 100), Partial(90..100));
        assert_eq!(parse_range(Some("bytes=99-99"), 100), Partial(99..100));
        assert_eq!(parse_range(Some("bytes=10-"), 100), Partial(10..100));
        assert_eq!(parse_range(Some("bytes=-10"), 100), Partial(90..100));
        assert_eq!(parse_range(Some("bytes=-1000"), 100), Partial(0..100));
    }

    #[test]
    fn unsatisfiable() {
        assert_eq!(parse_range(Some("bytes=100-"), 100), Unsatisfiable);
        assert_eq!(parse_range(Some("bytes=100-200"), 100), Unsatisfiable);
        assert_eq!(parse_range(Some("bytes=-0"), 100), Unsatisfiable);
        assert_eq!(parse_range(Some("bytes=0-"), 0), Unsatisfiable);
        assert_eq!(parse_range(Some("bytes=-5"), 0), Unsatisfiable);
    }

    #[test]
    fn ignored() {
        for h in [
            "bytes=5-2",
            "bytes=a-b",
            "bytes=+1-2",
            "bytes=-",
            "items=0-1",
            "bytes=0-1,5-6",
            "bytes 0-1",
            "bytes=18446744073709551616-",
        ] {
            assert_eq!(parse_range(Some(h), 100), Full, "{h}");
        }
        assert_eq!(parse_range(None, 100), Full);
    }
}
