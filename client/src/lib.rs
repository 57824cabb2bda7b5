//! The C-BDAM client: data access, time-critical refinement and rendering (`cbdam view`).
//!
//! Not implemented yet: issues 5 and 6.
#![deny(missing_docs)]
