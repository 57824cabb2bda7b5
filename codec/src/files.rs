//! Files the codec and the builder open: special files (FIFOs, sockets, devices) are refused by
//! their type before they are opened, since opening or reading one can block forever.

use std::path::Path;

use crate::CodecError;

/// Refuses a path that exists but is not a regular file — a FIFO, a socket, a device, a
/// directory — by its type, before anything opens it: opening a FIFO for reading waits for a
/// writer, forever if none comes, and a device may never end. Symlinks are followed. A path
/// that does not exist is left to the open that follows, which names it.
///
/// # Errors
/// [`CodecError::InvalidParameter`] naming the file and what it is.
pub fn check_regular_file(path: &Path) -> Result<(), CodecError> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => Err(CodecError::invalid(format!(
            "{} is {}, not a regular file",
            path.display(),
            file_kind(&m.file_type())
        ))),
        _ => Ok(()),
    }
}

/// What a file type is, in words.
fn file_kind(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_block_device() || t.is_char_device() {
            return "a device";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "a special file"
    }
}
