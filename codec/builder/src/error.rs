//! The build's one error type, and the helpers that name the file or option at fault.

use cbdam_codec::CodecError;

/// Everything that can go wrong in a build, a verification or a DEM write.
///
/// Messages name the file or option at fault. A step that failed on a file carries the step
/// ([`BuildError::Context`], e.g. "reading data/x.tif") in front of its cause, in one message:
/// like [`CodecError`], no variant is also its cause's `source`, so error chains print each part
/// once.
#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    /// An option or input the build cannot use (the message says which and why).
    #[error("{0}")]
    Invalid(String),
    /// A step on a named file or stage failed; `cause` says how.
    #[error("{context}: {cause}")]
    Context {
        /// What was being done, naming the file or option (e.g. "reading data/x.tif").
        context: String,
        /// Why it failed.
        cause: Box<dyn std::error::Error + Send + Sync + 'static>,
    },
    /// An error of the codec.
    #[error(transparent)]
    Codec(#[from] CodecError),
    /// An I/O error.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// An error of the TIFF encoder.
    #[error(transparent)]
    Tiff(#[from] tiff::TiffError),
    /// The worker thread pool could not be started.
    #[error(transparent)]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
}

/// The library's result type.
pub type Result<T, E = BuildError> = std::result::Result<T, E>;

/// Returns early with [`BuildError::Invalid`] and a formatted message.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err($crate::BuildError::Invalid(format!($($arg)*)))
    };
}
pub(crate) use bail;

/// Puts what was being done in front of an error ([`BuildError::Context`]).
pub(crate) trait Context<T> {
    /// The error, after `f()` says what was being done.
    fn with_context(self, f: impl FnOnce() -> String) -> Result<T>;
    /// The error, after `what` says what was being done.
    fn context(self, what: &str) -> Result<T>;
}

impl<T, E> Context<T> for std::result::Result<T, E>
where
    E: Into<Box<dyn std::error::Error + Send + Sync + 'static>>,
{
    fn with_context(self, f: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| BuildError::Context {
            context: f(),
            cause: e.into(),
        })
    }

    fn context(self, what: &str) -> Result<T> {
        self.with_context(|| what.to_string())
    }
}
