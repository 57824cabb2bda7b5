//! A disk that fills during a build (`docs/BUILD.md`, "A disk that fills"): the write that
//! failed already names its file (the repository's temporary beside `-o`, a journal block, a
//! temporary); this says that the disk is full, and that the build continues from its journal
//! when run again once space is freed. Nothing is left at `-o`: the repository is written to a
//! temporary that is removed when a write fails ([`cbdam_codec::atomic`]), and journal blocks
//! are renamed into place whole.

use std::error::Error;
use std::io::ErrorKind;
use std::path::Path;

use cbdam_codec::CodecError;

use crate::BuildError;
use crate::journal::Journal;

/// Why a write found no room, if the error (or a cause in its chain) is one: a full disk, a
/// quota, or a file-size limit (`ulimit -f`).
pub fn no_room(e: &(dyn Error + 'static)) -> Option<&'static str> {
    let mut next: Option<&(dyn Error + 'static)> = Some(e);
    while let Some(e) = next {
        let io = match e.downcast_ref::<BuildError>() {
            Some(BuildError::Io(io)) => Some(io),
            Some(BuildError::Codec(CodecError::Io(io))) => Some(io),
            Some(BuildError::Context { cause, .. }) => {
                next = Some(cause.as_ref());
                continue;
            }
            _ => match e.downcast_ref::<CodecError>() {
                Some(CodecError::Io(io)) => Some(io),
                _ => e.downcast_ref::<std::io::Error>(),
            },
        };
        if let Some(why) = io.and_then(|io| match io.kind() {
            ErrorKind::StorageFull => Some("the disk is full"),
            ErrorKind::QuotaExceeded => Some("the disk quota is exceeded"),
            ErrorKind::FileTooLarge => Some("a file reached the file-size limit (ulimit -f)"),
            _ => None,
        }) {
            return Some(why);
        }
        next = e.source();
    }
    None
}

/// `e` with what to do when it is a write that found no room: free space and run the build
/// again, which continues from the blocks its journal kept (if it has one).
pub(crate) fn explain(e: BuildError, output: &Path) -> BuildError {
    let Some(why) = no_room(&e) else {
        return e;
    };
    let journal = Journal::dir_of(output);
    let blocks = std::fs::read_dir(&journal).map_or(0, |d| {
        d.filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with("block-"))
            .count()
    });
    let resume = if blocks > 0 {
        format!(
            "; {blocks} finished blocks are kept in {} and the build continues from them",
            journal.display()
        )
    } else {
        String::new()
    };
    BuildError::Invalid(format!(
        "{e}\n{why}: nothing was written at {}; make room and run the same command again{resume}",
        output.display()
    ))
}
