//! (being written in a parallel branch; placeholder so the crate compiles)
use super::{Band, BandMut, DecodeLimits};
use crate::CodecError;

pub(crate) fn encode_bands(_bands: &[Band<'_>], _out: &mut Vec<u8>) {
    unimplemented!("coder not written yet")
}

pub(crate) fn decode_bands(
    _bytes: &[u8],
    _bands: &mut [BandMut<'_>],
    _limits: DecodeLimits,
) -> Result<(), CodecError> {
    Err(CodecError::unsupported("coder not written yet"))
}
