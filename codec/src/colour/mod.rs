//! Colour repositories (paper §5, "Managing multiple vertex attributes"): a second, optional
//! repository over the same diamond domain as an elevation one, with the same patch size and
//! possibly a different depth.
//!
//! 8-bit RGB is mapped to YCoCg-R ([`ycocg`], lossless and integer), and each of Y, Co, Cg is
//! coded by the elevation codec unchanged (integer unit 1, lattice input): the hierarchy
//! encoder runs once per channel and [`channels`] interleaves the three results per diamond,
//! so one record — one range request — holds all three components. `--max-error E` is a bound
//! in RGB: each channel gets the largest `k` with [`ycocg::rgb_bound`]`(k) ≤ E`.
//!
//! [`align`] says how a colour repository's diamonds correspond to an elevation repository's.

pub mod align;
pub mod channels;
mod decode;
mod encode;
pub mod ycocg;

pub use align::Alignment;
pub use decode::{
    ColourDecoder, ColourRefined, ColourVerifyReport, reconstruct_rgb, verify_colour,
};
pub use encode::{colour_plan, encode_colour};

use crate::repository::GeoRef;

/// An 8-bit RGB image, row-major, row 0 = north (alpha, if the file had it, dropped).
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width × height` pixels.
    pub pixels: Vec<[u8; 3]>,
    /// Where the image lies, when the file says.
    pub georef: Option<GeoRef>,
}
