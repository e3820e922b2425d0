//! gonio-files: how gonio reads and writes files it does not trust or must not lose.
//!
//! - [`input`]: bounded reads of input files a user or a client names (regular files
//!   only, a size cap before reading), used by every reader of one.
//! - [`output`]: atomic writes of outputs under unique temporary names, never replacing
//!   what is not a regular file.
//! - [`beneath`]: opening a file below a directory by handle, following no link.
//! - [`walk`]: every regular file below a directory, visited by handle.
//! - [`scan_layout`]: the naming of a scan directory's θL directories.

pub mod beneath;
pub mod input;
pub mod output;
pub mod scan_layout;
pub mod walk;

/// Makes a FIFO at `path`, for tests.
#[cfg(test)]
fn mkfifo(path: &std::path::Path) {
    let c_path = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
}
