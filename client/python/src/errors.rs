//! The package's one error type, sorted by who is to blame, and the Python exceptions it
//! becomes: `cbdam.Error` and its subclasses, each carrying the CLI's message.

use cbdam_builder::BuildError;
use cbdam_client::fetch::RemoteError;
use cbdam_codec::CodecError;
use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::PyException;

create_exception!(
    cbdam,
    Error,
    PyException,
    "Every error of cbdam: the subclasses say who is to blame."
);
create_exception!(
    cbdam,
    CorruptError,
    Error,
    "The repository's bytes are damaged or truncated (a checksum, a record, the header)."
);
create_exception!(
    cbdam,
    InputError,
    Error,
    "An argument or input file cannot be used (the message names it and why)."
);
create_exception!(
    cbdam,
    UnsupportedError,
    Error,
    "A well-formed repository or input uses something this version does not read."
);
create_exception!(
    cbdam,
    NetworkError,
    Error,
    "A remote repository could not be reached, or stopped answering."
);
create_exception!(
    cbdam,
    IoError,
    Error,
    "Reading or writing a file failed (the operating system's message)."
);

/// What went wrong, by who is to blame.
#[derive(Debug)]
pub enum PyCbdamError {
    /// The bytes of a repository.
    Corrupt(String),
    /// The caller's arguments or input files.
    Input(String),
    /// Something this version does not implement.
    Unsupported(String),
    /// The network or the server.
    Network(String),
    /// The file system.
    Io(String),
    /// Anything else (a thread pool that would not start).
    Other(String),
}

impl PyCbdamError {
    /// The codec's error `e` after `context` (what was being done, naming the file), sorted
    /// by the codec's own blame.
    pub fn codec(context: &str, e: &CodecError) -> Self {
        let message = format!("{context}: {e}");
        match e {
            CodecError::Io(_) => Self::Io(message),
            CodecError::Corrupt(_) | CodecError::Truncated(_) => Self::Corrupt(message),
            CodecError::Unsupported(_) => Self::Unsupported(message),
            CodecError::InvalidParameter(_) | CodecError::LimitExceeded(_) => Self::Input(message),
        }
    }

    /// Connecting to a remote repository failed.
    pub fn remote(e: &RemoteError) -> Self {
        match e {
            RemoteError::Http { .. } => Self::Network(e.to_string()),
            RemoteError::Repository { url, source } => Self::codec(url, source),
            RemoteError::Url(_) => Self::Input(e.to_string()),
        }
    }

    /// A build or a comparison of the builder failed.
    pub fn build(e: &BuildError) -> Self {
        match e {
            BuildError::Invalid(m) => Self::Input(m.clone()),
            BuildError::Codec(c) => Self::codec("build", c),
            BuildError::Io(_) => Self::Io(e.to_string()),
            BuildError::Tiff(_) => Self::Input(e.to_string()),
            BuildError::Context { cause, .. } => {
                if let Some(c) = cause.downcast_ref::<CodecError>() {
                    // The context already names the file: keep the message as the CLI prints it.
                    let sorted = Self::codec("", c);
                    return sorted.with_message(e.to_string());
                }
                if cause.downcast_ref::<std::io::Error>().is_some() {
                    return Self::Io(e.to_string());
                }
                Self::Input(e.to_string())
            }
            BuildError::ThreadPool(_) => Self::Other(e.to_string()),
        }
    }

    fn with_message(self, m: String) -> Self {
        match self {
            Self::Corrupt(_) => Self::Corrupt(m),
            Self::Input(_) => Self::Input(m),
            Self::Unsupported(_) => Self::Unsupported(m),
            Self::Network(_) => Self::Network(m),
            Self::Io(_) => Self::Io(m),
            Self::Other(_) => Self::Other(m),
        }
    }
}

impl From<PyCbdamError> for PyErr {
    fn from(e: PyCbdamError) -> PyErr {
        match e {
            PyCbdamError::Corrupt(m) => CorruptError::new_err(m),
            PyCbdamError::Input(m) => InputError::new_err(m),
            PyCbdamError::Unsupported(m) => UnsupportedError::new_err(m),
            PyCbdamError::Network(m) => NetworkError::new_err(m),
            PyCbdamError::Io(m) => IoError::new_err(m),
            PyCbdamError::Other(m) => Error::new_err(m),
        }
    }
}

/// The package's result type.
pub type Result<T, E = PyCbdamError> = std::result::Result<T, E>;
