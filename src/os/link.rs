//! Giving a name to an unnamed file (`O_TMPFILE`): how an output comes into being only when it
//! is complete, with no temporary name that a killed process could leave behind.

use std::ffi::CString;
use std::fs::File;
use std::os::fd::AsRawFd;
use std::os::unix::ffi::OsStrExt;
use std::path::Path;

/// Links the unnamed file `file` (opened with `O_TMPFILE` and without `O_EXCL`) at `name`,
/// which must not exist (`AlreadyExists` otherwise): `linkat` of `/proc/self/fd/N` with
/// `AT_SYMLINK_FOLLOW`, the documented way to name such a file.
pub fn link_unnamed(file: &File, name: &Path) -> std::io::Result<()> {
    let from = CString::new(format!("/proc/self/fd/{}", file.as_raw_fd()))?;
    let to = CString::new(name.as_os_str().as_bytes())?;
    // SAFETY: both paths are NUL-terminated strings that live across the call; `linkat` reads
    // them and writes no memory of ours. The descriptor is ours and open for the whole call.
    let r = unsafe {
        libc::linkat(
            libc::AT_FDCWD,
            from.as_ptr(),
            libc::AT_FDCWD,
            to.as_ptr(),
            libc::AT_SYMLINK_FOLLOW,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}
