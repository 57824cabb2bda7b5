//! Reserving a mapped temporary's disk blocks before it is mapped ([`reserve`]).
//!
//! A write through a shared mapping that finds the disk full cannot return an error: the
//! kernel raises `SIGBUS` and the process dies with no message. So a temporary that is mapped
//! for writing first gets its blocks from the file system (`posix_fallocate`; where that is
//! not supported, a zero byte written into every 4 KiB block, as glibc's own fallback does),
//! and a disk without room fails there, with an error naming the file and its directory.
//! Holds on file systems that write a file's blocks in place (ext4, XFS, tmpfs); a
//! copy-on-write one (ZFS, btrfs with snapshots) may still need new blocks when a reserved
//! block is written.

use std::fs::File;
use std::io;
use std::path::Path;

use crate::CodecError;

/// Sets `file` (a new, empty temporary for `what` in the directory `dir`: `name` is its path
/// when it has one, `None` when it was created unlinked) to `bytes` bytes, every one of them
/// on disk: writes through a shared mapping of it then never find the disk full. An error
/// keeps the system's error kind (a full disk is [`io::ErrorKind::StorageFull`]) and names the
/// file, its directory and its size.
pub(crate) fn reserve(
    file: &File,
    bytes: u64,
    what: &str,
    dir: &Path,
    name: Option<&Path>,
) -> Result<(), CodecError> {
    allocate(file, bytes).map_err(|e| {
        let file = match name {
            Some(name) => format!("{}", name.display()),
            None => format!("an unlinked file in {}", dir.display()),
        };
        CodecError::Io(io::Error::new(
            e.kind(),
            format!(
                "reserving {bytes} bytes for {what}'s temporary file ({file}; temporary \
                 directory {}): {e}",
                dir.display()
            ),
        ))
    })
}

/// `bytes` bytes of `file`, allocated.
#[cfg(any(target_os = "linux", target_os = "android", target_os = "freebsd"))]
fn allocate(file: &File, bytes: u64) -> io::Result<()> {
    use std::os::fd::AsRawFd;
    let len = libc::off_t::try_from(bytes)
        .map_err(|_| io::Error::new(io::ErrorKind::FileTooLarge, "past the largest file offset"))?;
    // SAFETY: a plain system call on a file descriptor this `File` owns.
    match unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, len) } {
        0 => Ok(()),
        libc::EOPNOTSUPP | libc::EINVAL | libc::ENOSYS => write_every_block(file, bytes),
        e => Err(io::Error::from_raw_os_error(e)),
    }
}

/// `bytes` bytes of `file`, allocated.
#[cfg(all(
    unix,
    not(any(target_os = "linux", target_os = "android", target_os = "freebsd"))
))]
fn allocate(file: &File, bytes: u64) -> io::Result<()> {
    write_every_block(file, bytes)
}

/// `bytes` bytes of `file`: on Windows a file that is not marked sparse gets its clusters
/// when its length is set.
#[cfg(not(unix))]
fn allocate(file: &File, bytes: u64) -> io::Result<()> {
    file.set_len(bytes)
}

/// Sets the length of `file` (new and empty, so all zeros) to `bytes` and writes a zero byte
/// into each of its 4 KiB blocks, which makes the file system allocate them.
#[cfg(unix)]
fn write_every_block(file: &File, bytes: u64) -> io::Result<()> {
    use std::os::unix::fs::FileExt;
    file.set_len(bytes)?;
    for at in (0..bytes).step_by(4096) {
        file.write_all_at(&[0], at)?;
    }
    Ok(())
}
