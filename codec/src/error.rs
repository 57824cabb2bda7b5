//! One error type for the codec, sorted by who is to blame.

use std::borrow::Cow;

/// Everything that can go wrong in the codec.
///
/// The variants say who is to blame: the environment ([`CodecError::Io`]), the bytes we were
/// handed ([`CodecError::Corrupt`], [`CodecError::Truncated`], [`CodecError::Unsupported`]), the
/// caller ([`CodecError::InvalidParameter`]) or a resource bound ([`CodecError::LimitExceeded`]).
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    /// Reading or writing a file failed.
    // The message includes the OS error, so it is not also the error's `source`: error chains
    // (`anyhow`'s `{:#}`) would print it twice.
    #[error("I/O error: {0}")]
    Io(std::io::Error),
    /// The data is internally inconsistent: a decoder met something no encoder writes.
    #[error("corrupt data: {0}")]
    Corrupt(Cow<'static, str>),
    /// The data ends before the decoder is done.
    #[error("truncated data: {0}")]
    Truncated(Cow<'static, str>),
    /// A well-formed input uses a feature this codec does not implement.
    #[error("unsupported input: {0}")]
    Unsupported(Cow<'static, str>),
    /// The caller asked for something that cannot be done (e.g. a tolerance the format cannot
    /// represent).
    #[error("invalid parameter: {0}")]
    InvalidParameter(Cow<'static, str>),
    /// A size or magnitude bound would be exceeded; checked before allocating.
    #[error("limit exceeded: {0}")]
    LimitExceeded(Cow<'static, str>),
}

impl From<std::io::Error> for CodecError {
    fn from(e: std::io::Error) -> Self {
        CodecError::Io(e)
    }
}

impl CodecError {
    /// A [`CodecError::Corrupt`] with a static or formatted message.
    pub fn corrupt(msg: impl Into<Cow<'static, str>>) -> Self {
        Self::Corrupt(msg.into())
    }
    /// A [`CodecError::Truncated`] with a static or formatted message.
    pub fn truncated(msg: impl Into<Cow<'static, str>>) -> Self {
        Self::Truncated(msg.into())
    }
    /// A [`CodecError::Unsupported`] with a static or formatted message.
    pub fn unsupported(msg: impl Into<Cow<'static, str>>) -> Self {
        Self::Unsupported(msg.into())
    }
    /// A [`CodecError::InvalidParameter`] with a static or formatted message.
    pub fn invalid(msg: impl Into<Cow<'static, str>>) -> Self {
        Self::InvalidParameter(msg.into())
    }
    /// A [`CodecError::LimitExceeded`] with a static or formatted message.
    pub fn limit(msg: impl Into<Cow<'static, str>>) -> Self {
        Self::LimitExceeded(msg.into())
    }
}
