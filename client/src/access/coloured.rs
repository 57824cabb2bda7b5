//! An elevation source with a colour repository draped over it (paper §5, "Managing multiple
//! vertex attributes"): one [`DataSource`] whose records are elevation–colour pairs.
//!
//! The refinement loop is driven by the elevation hierarchy alone (its index, errors and boxes);
//! the colour rides along. A diamond is available only when both its elevation record and the
//! record of the colour diamond covering the same ground ([`Alignment::colour_id`]) are, and
//! [`DataSource::take`] hands out both, [`join`]ed; the loop's decode workers [`split`] them and
//! decode each with its own decoder. Requests, cancellations and priorities go to both sources,
//! so nothing the cut does not need is fetched from either.
//!
//! Where the colour hierarchy has no record for a diamond (it is coarser than the elevation, so
//! it has no level that fine, or the diamond is not stored) the colour part is empty, which the
//! codec reads as "all residuals zero": the diamond's colour is the codec's own prediction from
//! its colour parents, i.e. the colour ancestor's interpolated.

use cbdam_codec::CodecError;
use cbdam_codec::colour::{Alignment, ColourDecoder};
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::RepositoryHead;

use super::{AccessError, AccessStats, DataSource, Priority};

/// What the decode workers need to decode the colour half of a paired record.
#[derive(Clone, Debug)]
pub struct Drape {
    /// The colour repository's three-channel decoder over its root field.
    pub decoder: ColourDecoder,
    /// How elevation ids map to colour ids.
    pub alignment: Alignment,
}

/// Bytes of the length prefix of a [`join`]ed record.
const PREFIX: usize = 4;

/// `u32 LE elevation length ‖ elevation ‖ colour`.
pub fn join(elevation: &[u8], colour: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(PREFIX + elevation.len() + colour.len());
    out.extend_from_slice(&(elevation.len() as u32).to_le_bytes());
    out.extend_from_slice(elevation);
    out.extend_from_slice(colour);
    out
}

/// The elevation and colour parts of a [`join`]ed record; a length that does not fit is
/// [`CodecError::Corrupt`], never a panic.
pub fn split(bytes: &[u8]) -> Result<(&[u8], &[u8]), CodecError> {
    let Some((len, rest)) = bytes.split_first_chunk::<PREFIX>() else {
        return Err(CodecError::corrupt(format!(
            "paired record of {} bytes lacks its {PREFIX}-byte length",
            bytes.len()
        )));
    };
    let len = u32::from_le_bytes(*len) as usize;
    if len > rest.len() {
        return Err(CodecError::corrupt(format!(
            "paired record: elevation part of {len} bytes in {} bytes",
            rest.len()
        )));
    }
    Ok(rest.split_at(len))
}

/// An elevation source `E` with the colour source `C` draped over it.
#[derive(Debug)]
pub struct ColouredSource<E, C> {
    elevation: E,
    colour: C,
    drape: Drape,
}

impl<E: DataSource, C: DataSource> ColouredSource<E, C> {
    /// Pairs the two, refusing a colour repository that does not cover the elevation's domain
    /// (or that is not a colour repository, or an elevation that is not an elevation one); the
    /// error names the mismatch.
    pub fn new(elevation: E, colour: C) -> Result<Self, CodecError> {
        let alignment = Alignment::new(
            elevation.head().params(),
            elevation.head().georef(),
            colour.head().params(),
            colour.head().georef(),
        )?;
        let decoder = ColourDecoder::new(*colour.head().params(), colour.head().root_bytes())?;
        if elevation
            .head()
            .params()
            .domain
            .roots()
            .any(|r| alignment.colour_id(r).is_none())
        {
            return Err(CodecError::invalid(
                "the colour repository's roots do not line up with the elevation's",
            ));
        }
        Ok(Self {
            elevation,
            colour,
            drape: Drape { decoder, alignment },
        })
    }

    /// The elevation source.
    pub fn elevation(&self) -> &E {
        &self.elevation
    }

    /// The colour source.
    pub fn colour(&self) -> &C {
        &self.colour
    }

    /// The colour record `id` needs: `None` when the colour hierarchy stores none for it (its
    /// colour is then predicted from its colour parents).
    pub fn colour_id(&self, id: DiamondId) -> Option<DiamondId> {
        let c = self.drape.alignment.colour_id(id)?;
        self.colour
            .head()
            .entries()
            .binary_search_by(|e| e.id.cmp(&c))
            .is_ok()
            .then_some(c)
    }
}

impl<E: DataSource, C: DataSource> DataSource for ColouredSource<E, C> {
    fn head(&self) -> &RepositoryHead {
        self.elevation.head()
    }
    fn drape(&self) -> Option<&Drape> {
        Some(&self.drape)
    }

    fn request(&mut self, id: DiamondId, priority: Priority) {
        self.elevation.request(id, priority);
        if let Some(c) = self.colour_id(id) {
            self.colour.request(c, priority);
        }
    }

    fn cancel(&mut self, id: DiamondId) {
        self.elevation.cancel(id);
        if let Some(c) = self.colour_id(id) {
            self.colour.cancel(c);
        }
    }

    fn is_available(&self, id: DiamondId) -> bool {
        self.elevation.is_available(id)
            && self
                .colour_id(id)
                .is_none_or(|c| self.colour.is_available(c))
    }

    fn always_available(&self) -> bool {
        self.elevation.always_available() && self.colour.always_available()
    }

    fn take(&mut self, id: DiamondId) -> Option<Result<Vec<u8>, AccessError>> {
        if !self.is_available(id) {
            return None;
        }
        let cid = self.colour_id(id);
        let elevation = self.elevation.take(id)?;
        let colour = match cid {
            Some(c) => self.colour.take(c)?,
            None => Ok(Vec::new()),
        };
        Some(match (elevation, colour) {
            (Ok(e), Ok(c)) => Ok(join(&e, &c)),
            (Err(e), _) => Err(e),
            (Ok(_), Err(AccessError::Record { source, .. })) => Err(AccessError::Record {
                id,
                source: CodecError::invalid(format!("its colour record: {source}")),
            }),
            (Ok(_), Err(AccessError::Transport { message, .. })) => Err(AccessError::Transport {
                id,
                message: format!("its colour record: {message}"),
            }),
        })
    }

    fn pump(&mut self) {
        self.elevation.pump();
        self.colour.pump();
    }

    /// Both sources' counters added up: requests and records of the two repositories, bytes of
    /// both.
    fn stats(&self) -> AccessStats {
        let (a, b) = (self.elevation.stats(), self.colour.stats());
        AccessStats {
            requests_issued: a.requests_issued + b.requests_issued,
            requests_cancelled: a.requests_cancelled + b.requests_cancelled,
            in_flight: a.in_flight + b.in_flight,
            records_taken: a.records_taken + b.records_taken,
            bytes_fetched: a.bytes_fetched + b.bytes_fetched,
            errors: a.errors + b.errors,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn join_split_round_trip_and_refusals() {
        let j = join(b"elev", b"rgb!");
        assert_eq!(split(&j).unwrap(), (&b"elev"[..], &b"rgb!"[..]));
        assert_eq!(split(&join(b"", b"")).unwrap(), (&b""[..], &b""[..]));
        assert!(split(&j[..3]).is_err());
        let mut bad = j.clone();
        bad[3] = 0xFF;
        assert!(split(&bad).is_err());
        assert!(split(&[]).is_err());
    }
}
