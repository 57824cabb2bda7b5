//! How a colour repository's root field and records hold three channels (`docs/FORMAT.md`,
//! "Colour repositories"): `u32 len_Y ‖ u32 len_Co ‖ Y ‖ Co ‖ Cg`, each part exactly what the
//! elevation codec writes for one channel; Cg takes the rest. A record whose three parts are all
//! empty (all residuals zero) is stored empty, like an elevation record.

use crate::CodecError;

/// Bytes of the length prefix.
pub const PREFIX: usize = 8;

/// Joins three channel parts; with `keep_empty` false, three empty parts give an empty string.
pub fn join(parts: [&[u8]; 3], keep_empty: bool) -> Vec<u8> {
    if !keep_empty && parts.iter().all(|p| p.is_empty()) {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(PREFIX + parts.iter().map(|p| p.len()).sum::<usize>());
    out.extend_from_slice(&(parts[0].len() as u32).to_le_bytes());
    out.extend_from_slice(&(parts[1].len() as u32).to_le_bytes());
    for p in parts {
        out.extend_from_slice(p);
    }
    out
}

/// Splits a joined string into its Y, Co, Cg parts; an empty string is three empty parts when
/// `allow_empty`. Lengths that do not fit are [`CodecError::Corrupt`], never a panic.
pub fn split<'a>(
    bytes: &'a [u8],
    allow_empty: bool,
    what: &str,
) -> Result<[&'a [u8]; 3], CodecError> {
    if bytes.is_empty() && allow_empty {
        return Ok([&[], &[], &[]]);
    }
    if bytes.len() < PREFIX {
        return Err(CodecError::corrupt(format!(
            "colour {what} is {} bytes, shorter than its {PREFIX}-byte channel lengths",
            bytes.len()
        )));
    }
    let len = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4")) as u64;
    let (ly, lco) = (len(0), len(4));
    let rest = (bytes.len() - PREFIX) as u64;
    if ly + lco > rest {
        return Err(CodecError::corrupt(format!(
            "colour {what}: channel lengths {ly} + {lco} exceed the {rest} bytes that follow"
        )));
    }
    let (ly, lco) = (ly as usize, lco as usize);
    let body = &bytes[PREFIX..];
    Ok([&body[..ly], &body[ly..ly + lco], &body[ly + lco..]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_refusals() {
        let parts: [&[u8]; 3] = [b"ab", b"", b"xyz"];
        let j = join(parts, false);
        assert_eq!(split(&j, true, "record").unwrap(), parts);
        assert!(join([b"", b"", b""], false).is_empty());
        assert_eq!(join([b"", b"", b""], true).len(), PREFIX);
        assert_eq!(split(&[], true, "record").unwrap(), [b"" as &[u8]; 3]);
        assert!(split(&[], false, "root field").is_err());
        assert!(split(&j[..5], true, "record").is_err());
        let mut bad = j.clone();
        bad[0] = 200;
        assert!(split(&bad, true, "record").is_err());
        // Lengths near u32::MAX must not overflow.
        let mut huge = vec![0xFF; PREFIX];
        huge.push(1);
        assert!(split(&huge, true, "record").is_err());
    }
}
