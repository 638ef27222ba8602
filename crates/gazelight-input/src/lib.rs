//! One way to open an input file, shared by every importer, the scene
//! loader and the config loaders.
//!
//! A path given by a user can name anything: a FIFO (whose `open` blocks
//! until a writer appears, and whose reads block until it writes), a
//! character device such as `/dev/zero` (endless) or `/dev/tty`, a socket,
//! a directory, or a regular file far larger than it should be. So:
//!
//! - [`open`] opens with `O_NONBLOCK` (an `open` of a FIFO returns at once)
//!   and then checks the *opened* descriptor with `fstat`: anything but a
//!   regular file is refused with an error naming what it is. Checking the
//!   descriptor rather than the path leaves no window for a swap between
//!   the check and the open. `O_NONBLOCK` has no effect on regular files.
//! - [`read`] and [`read_to_string`] read a whole file only up to a limit
//!   (checked against the size first, and enforced while reading in case
//!   the file grows).
//! - [`read_line`] reads one line of a text file with a bounded length, so
//!   that a 200 MB file without a newline never becomes a 200 MB `String`.
//!
//! Every error is a [`std::io::Error`] whose message says what was wrong,
//! so the callers' "cannot read {path}: {error}" messages stay as they are.

use std::fs::File;
use std::io::{self, BufRead, Read};
use std::path::Path;

/// Largest scene file read whole (an 8k×4k RGBA float32 EXR is 512 MiB
/// uncompressed).
pub const MAX_SCENE_BYTES: u64 = 1 << 30;
/// Largest small text/JSON/TOML file read whole (configs, `info.json`,
/// `.dtype`, calibration profiles, traces).
pub const MAX_TEXT_BYTES: u64 = 64 << 20;
/// Longest line of a streamed text recording (CSV, ASC). Real lines are
/// under 200 bytes.
pub const MAX_LINE_BYTES: usize = 64 << 10;

/// What kind of file a path or descriptor is, for error messages.
fn kind_name(ft: std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if ft.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if ft.is_char_device() {
            return "a character device (an endless or interactive stream such as /dev/zero)";
        }
        if ft.is_block_device() {
            return "a block device";
        }
        if ft.is_socket() {
            return "a socket";
        }
    }
    if ft.is_dir() {
        return "a directory";
    }
    "not a regular file"
}

fn not_regular(ft: std::fs::FileType) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!(
            "it is {}; inputs are read only from regular files",
            kind_name(ft)
        ),
    )
}

/// Opens `path` for reading if it is a regular file (symlinks followed);
/// never blocks on a FIFO.
pub fn open(path: &Path) -> io::Result<File> {
    let mut opts = std::fs::OpenOptions::new();
    opts.read(true);
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // O_NONBLOCK (linux, all architectures but alpha/sparc/parisc which
        // std does not support as hosts for this project): an open of a
        // FIFO with no writer returns at once instead of blocking.
        const O_NONBLOCK: i32 = 0o4000;
        opts.custom_flags(O_NONBLOCK);
    }
    #[cfg(all(unix, not(target_os = "linux")))]
    {
        // Elsewhere: refuse by the path's type before opening (a small race
        // window, but no blocking open of a FIFO in the common case).
        let meta = std::fs::metadata(path)?;
        if !meta.is_file() {
            return Err(not_regular(meta.file_type()));
        }
    }
    let file = opts.open(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(not_regular(meta.file_type()));
    }
    Ok(file)
}

/// Opens `path` (see [`open`]) and checks that it holds at most
/// `max_bytes`; returns the file and its size.
pub fn open_with_limit(path: &Path, max_bytes: u64) -> io::Result<(File, u64)> {
    let file = open(path)?;
    let len = file.metadata()?.len();
    if len > max_bytes {
        return Err(too_large(len, max_bytes));
    }
    Ok((file, len))
}

fn too_large(len: u64, max_bytes: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!(
            "the file holds {len} bytes, more than the limit of {max_bytes} bytes for this kind of input"
        ),
    )
}

/// Reads a whole regular file of at most `max_bytes`.
pub fn read(path: &Path, max_bytes: u64) -> io::Result<Vec<u8>> {
    let (file, len) = open_with_limit(path, max_bytes)?;
    let mut bytes = Vec::with_capacity(len as usize);
    // One byte past the limit tells a file that grew while being read.
    file.take(max_bytes + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(bytes.len() as u64, max_bytes));
    }
    Ok(bytes)
}

/// Reads a whole regular UTF-8 text file of at most `max_bytes`.
pub fn read_to_string(path: &Path, max_bytes: u64) -> io::Result<String> {
    let bytes = read(path, max_bytes)?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!("not UTF-8 text (invalid byte at offset {at})"),
        )
    })
}

/// The result of [`read_line`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Line {
    /// End of input: nothing was read.
    Eof,
    /// A line (its text, with the newline, is in the buffer).
    Read,
    /// The line was longer than the limit: it was read to its end and
    /// dropped; the buffer is empty. Holds the line's length in bytes.
    TooLong(u64),
    /// The line is not valid UTF-8; the buffer is empty.
    NotUtf8,
}

/// Reads one `\n`-terminated line into `buf` (cleared first), keeping at
/// most `max_bytes` of it in memory. A longer line is consumed to its end
/// and reported as [`Line::TooLong`].
pub fn read_line(
    reader: &mut impl BufRead,
    buf: &mut String,
    max_bytes: usize,
) -> io::Result<Line> {
    buf.clear();
    let mut bytes = std::mem::take(buf).into_bytes();
    let mut total: u64 = 0;
    let mut too_long = false;
    loop {
        let chunk = match reader.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => {
                bytes.clear();
                *buf = String::from_utf8(bytes).unwrap_or_default();
                return Err(e);
            }
        };
        if chunk.is_empty() {
            break;
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        total += take as u64;
        if !too_long {
            if bytes.len() + take > max_bytes {
                too_long = true;
                bytes.clear();
            } else {
                bytes.extend_from_slice(&chunk[..take]);
            }
        }
        reader.consume(take);
        if done {
            break;
        }
    }
    if too_long {
        *buf = String::from_utf8(bytes).unwrap_or_default();
        return Ok(Line::TooLong(total));
    }
    if total == 0 {
        *buf = String::from_utf8(bytes).unwrap_or_default();
        return Ok(Line::Eof);
    }
    match String::from_utf8(bytes) {
        Ok(s) => {
            *buf = s;
            Ok(Line::Read)
        }
        Err(e) => {
            let mut b = e.into_bytes();
            b.clear();
            *buf = String::from_utf8(b).unwrap_or_default();
            Ok(Line::NotUtf8)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("gazelight-input-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn regular_file_reads() {
        let d = tmp("regular");
        let p = d.join("a.txt");
        std::fs::write(&p, "hello\n").unwrap();
        assert_eq!(read_to_string(&p, 100).unwrap(), "hello\n");
        let e = read(&p, 3).unwrap_err();
        assert!(
            e.to_string().contains("6 bytes, more than the limit of 3"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn dev_zero_and_directories_are_refused_at_once() {
        let t = Instant::now();
        let e = read(Path::new("/dev/zero"), MAX_TEXT_BYTES).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let d = tmp("dir");
        let link = d.join("endless.csv");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let e = open(&link).unwrap_err();
        assert!(e.to_string().contains("character device"), "{e}");
        let e = open(&d).unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        assert!(t.elapsed() < Duration::from_secs(2));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn fifo_is_refused_without_blocking() {
        let d = tmp("fifo");
        let fifo = d.join("pipe.csv");
        let ok = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .map(|s| s.success())
            .unwrap_or(false);
        assert!(ok, "mkfifo failed");
        // Run on a thread so a regression fails the test instead of hanging it.
        let (tx, rx) = std::sync::mpsc::channel();
        let p = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(open(&p).map(|_| ()).map_err(|e| e.to_string()));
        });
        let r = rx
            .recv_timeout(Duration::from_secs(5))
            .expect("open of a FIFO blocked for 5 s");
        let e = r.unwrap_err();
        assert!(e.contains("FIFO"), "{e}");
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn long_lines_are_bounded() {
        let mut text = "a,b\n".to_string();
        text.push_str(&"x".repeat(10_000));
        text.push_str("\nlast");
        let mut r = std::io::BufReader::with_capacity(64, text.as_bytes());
        let mut buf = String::new();
        assert_eq!(read_line(&mut r, &mut buf, 100).unwrap(), Line::Read);
        assert_eq!(buf, "a,b\n");
        assert_eq!(
            read_line(&mut r, &mut buf, 100).unwrap(),
            Line::TooLong(10_001)
        );
        assert!(
            buf.is_empty() && buf.capacity() <= 200,
            "{}",
            buf.capacity()
        );
        assert_eq!(read_line(&mut r, &mut buf, 100).unwrap(), Line::Read);
        assert_eq!(buf, "last");
        assert_eq!(read_line(&mut r, &mut buf, 100).unwrap(), Line::Eof);
        let mut r = &b"\xff\xfe\n"[..];
        assert_eq!(read_line(&mut r, &mut buf, 100).unwrap(), Line::NotUtf8);
    }
}
