//! The HTTP server of diamond residuals (`cbdam serve`).
//!
//! Not implemented yet: it is issue 4 and depends on the repository format (issue 3).
#![deny(missing_docs)]
