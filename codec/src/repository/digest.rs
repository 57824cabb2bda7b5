//! A digest of a repository's decoded surface: 64-bit FNV-1a over every diamond the whole walk
//! visits (every level, the leaves of a variable-resolution hierarchy too), in the walk's order —
//! its id, its reconstructed grid in integer units and its validity. Two decoders agree bit for
//! bit on a repository exactly when (but for a collision) their digests agree: `cbdam inspect
//! --digest` prints it natively, and the browser test compares it with the same function
//! compiled to wasm32 in the page; two coders of one surface give one digest.

use crate::error::CodecError;
use crate::hierarchy::walk_all_with_validity;

use super::Repository;

/// What [`decoded_digest`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DecodedDigest {
    /// 64-bit FNV-1a of the walk (see the module's documentation).
    pub fnv1a64: u64,
    /// Diamonds visited.
    pub diamonds: u64,
    /// Grid samples hashed.
    pub samples: u64,
}

/// FNV-1a's 64-bit offset basis and prime (Fowler, Noll, Vo).
const OFFSET_BASIS: u64 = 0xcbf2_9ce4_8422_2325;
const PRIME: u64 = 0x0000_0100_0000_01b3;

fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for &b in bytes {
        h = (h ^ u64::from(b)).wrapping_mul(PRIME);
    }
    h
}

/// Decodes all of `repo` and digests what every diamond decodes to.
pub fn decoded_digest(repo: &Repository) -> Result<DecodedDigest, CodecError> {
    let encoded = repo.to_encoded()?;
    let mut d = DecodedDigest {
        fnv1a64: OFFSET_BASIS,
        diamonds: 0,
        samples: 0,
    };
    walk_all_with_validity(&encoded, |id, grid, valid| {
        let mut h = fnv(d.fnv1a64, &[id.level, id.face]);
        h = fnv(h, &id.x.to_le_bytes());
        h = fnv(h, &id.y.to_le_bytes());
        for v in grid {
            h = fnv(h, &v.to_le_bytes());
        }
        // The validity as one byte a sample; an all-valid grid hashes as a marker byte.
        match valid {
            None => h = fnv(h, &[2]),
            Some(valid) => {
                for &v in valid {
                    h = fnv(h, &[u8::from(v)]);
                }
            }
        }
        d.fnv1a64 = h;
        d.diamonds += 1;
        d.samples += grid.len() as u64;
    })?;
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a_matches_the_reference_vectors() {
        // The FNV reference test suite's FNV-1a 64-bit vectors.
        assert_eq!(fnv(OFFSET_BASIS, b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv(OFFSET_BASIS, b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv(OFFSET_BASIS, b"foobar"), 0x8594_4171_f739_67e8);
    }
}
