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
//!   Its core, [`LineAccumulator`], takes the bytes chunk by chunk and
//!   stops keeping them at the limit, *while* reading: the line readers of
//!   network and serial sources (sync or async) use it the same way.
//!
//! - [`read_config`] reads a TOML or JSON config, profile or metadata file
//!   bounded in memory by construction: at most [`MAX_CONFIG_BYTES`], and
//!   a scan of its text ([`check_config_structure`]) refuses more values or
//!   deeper nesting than any valid one holds before a parser builds
//!   anything (a 20 M-element array would take gigabytes as a parsed tree).
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
/// Largest config, calibration profile or recording metadata file read
/// (TOML or JSON). The largest valid one, a service config with every
/// section and its comments, is under 8 KiB; a profile is under 1 KiB.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;
/// Most values a config may hold (array elements, table and object
/// entries, dotted-key parts, counted from the text's separators): valid
/// configs hold under 200.
pub const MAX_CONFIG_VALUES: usize = 10_000;
/// Deepest nesting of arrays, tables and objects (and dotted keys) in a
/// config: valid configs nest 3 deep.
pub const MAX_CONFIG_DEPTH: usize = 32;
/// Longest line of a streamed text recording (CSV, ASC). Real lines are
/// under 200 bytes.
pub const MAX_LINE_BYTES: usize = 64 << 10;

/// Most bytes a compressed input (a `.tsv.gz`) may expand to, as a
/// multiple of its compressed size. Real recordings' TSVs compress 3–15×
/// (time stamps and samples differ row to row); gzip's own ceiling is
/// ~1032×, reached only by made-up repetitive data.
pub const MAX_EXPANSION_RATIO: u64 = 64;
/// Expansion always allowed whatever the ratio (a small compressed file of
/// many blank cells may exceed the ratio harmlessly).
pub const MIN_EXPANSION_BYTES: u64 = 16 << 20;

/// A reader of decompressed bytes that stops with an error once more than
/// [`ExpansionLimit::limit_for`] of its compressed size came out: a few
/// megabytes of gzip cannot become minutes of parsing and gigabytes of
/// samples. Wrap the decoder (`ExpansionLimit::new(GzDecoder::new(file),
/// file_len)`).
pub struct ExpansionLimit<R> {
    inner: R,
    compressed: u64,
    limit: u64,
    out: u64,
}

impl<R> ExpansionLimit<R> {
    /// `inner` yields the decompressed bytes of a file of `compressed_len`
    /// bytes.
    pub fn new(inner: R, compressed_len: u64) -> Self {
        Self {
            inner,
            compressed: compressed_len,
            limit: Self::limit_for(compressed_len),
            out: 0,
        }
    }

    /// The most decompressed bytes allowed for `compressed_len` bytes:
    /// [`MAX_EXPANSION_RATIO`] times, at least [`MIN_EXPANSION_BYTES`].
    pub fn limit_for(compressed_len: u64) -> u64 {
        compressed_len
            .saturating_mul(MAX_EXPANSION_RATIO)
            .max(MIN_EXPANSION_BYTES)
    }

    /// Decompressed bytes read so far.
    pub fn bytes_out(&self) -> u64 {
        self.out
    }
}

impl<R: Read> Read for ExpansionLimit<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.out > self.limit {
            return Err(self.exceeded());
        }
        // Never hand out more than one byte past the limit.
        let room = usize::try_from(self.limit + 1 - self.out).unwrap_or(usize::MAX);
        let n = buf.len().min(room);
        let got = self.inner.read(&mut buf[..n])?;
        self.out += got as u64;
        if self.out > self.limit {
            return Err(self.exceeded());
        }
        Ok(got)
    }
}

impl<R> ExpansionLimit<R> {
    fn exceeded(&self) -> io::Error {
        io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "the compressed file of {} bytes expands to more than {} bytes \
                 ({MAX_EXPANSION_RATIO}× its size, at least {MIN_EXPANSION_BYTES} bytes, \
                 is the limit for compressed inputs); it is not a recording's table",
                self.compressed, self.limit
            ),
        )
    }
}

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

/// The syntax of a config file, for [`check_config_structure`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConfigSyntax {
    /// TOML (render and service configs).
    Toml,
    /// JSON (calibration profiles, recording metadata).
    Json,
}

/// Reads a whole config file (see [`read_to_string`]) of at most
/// [`MAX_CONFIG_BYTES`] and checks its structure with
/// [`check_config_structure`] before anyone parses it.
pub fn read_config(path: &Path, syntax: ConfigSyntax) -> io::Result<String> {
    let text = read_to_string(path, MAX_CONFIG_BYTES)?;
    check_config_structure(&text, syntax)?;
    Ok(text)
}

/// Refuses a config text with more values than [`MAX_CONFIG_VALUES`] or
/// nesting deeper than [`MAX_CONFIG_DEPTH`], in one pass over the bytes
/// with constant memory, so that a parser never builds the tree of a
/// hostile file. Strings (with their escapes) and TOML comments are
/// skipped; every structural separator outside them counts as a value
/// (`,` `[` `{`, and `=` `.` in TOML or `:` in JSON), an upper bound on the
/// values a parser would build. Malformed text passes (the parser reports
/// it, naming the line).
pub fn check_config_structure(text: &str, syntax: ConfigSyntax) -> io::Result<()> {
    let b = text.as_bytes();
    let mut values: usize = 0;
    let mut depth: usize = 0;
    // Dots since the last separator: a dotted key `a.b.c` nests tables.
    let mut dots: usize = 0;
    let mut i = 0;
    let toml = syntax == ConfigSyntax::Toml;
    let refuse = |what: String| io::Error::new(io::ErrorKind::InvalidData, what);
    while i < b.len() {
        let c = b[i];
        match c {
            b'"' | b'\'' => {
                let literal = c == b'\'' && toml;
                if c == b'\'' && !toml {
                    i += 1;
                    continue;
                }
                let triple = toml && b[i..].starts_with(if literal { b"'''" } else { b"\"\"\"" });
                let quote: &[u8] = match (triple, literal) {
                    (true, true) => b"'''",
                    (true, false) => b"\"\"\"",
                    (false, true) => b"'",
                    (false, false) => b"\"",
                };
                i += quote.len();
                while i < b.len() && !b[i..].starts_with(quote) {
                    // A backslash escapes the next byte in basic strings.
                    i += if b[i] == b'\\' && !literal { 2 } else { 1 };
                }
                i += quote.len();
                continue;
            }
            b'#' if toml => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
                continue;
            }
            b'[' | b'{' => {
                values += 1;
                depth += 1;
                dots = 0;
            }
            b']' | b'}' => {
                depth = depth.saturating_sub(1);
                dots = 0;
            }
            b',' | b'\n' => {
                if c == b',' {
                    values += 1;
                }
                dots = 0;
            }
            b'=' if toml => {
                values += 1;
                dots = 0;
            }
            b':' if !toml => values += 1,
            b'.' if toml => {
                values += 1;
                dots += 1;
            }
            _ => {}
        }
        if values > MAX_CONFIG_VALUES {
            return Err(refuse(format!(
                "more than {MAX_CONFIG_VALUES} values (array elements, entries) by byte {i}; \
                 no valid config holds that many"
            )));
        }
        if depth + dots > MAX_CONFIG_DEPTH {
            return Err(refuse(format!(
                "nested deeper than {MAX_CONFIG_DEPTH} levels at byte {i}; no valid config is"
            )));
        }
        i += 1;
    }
    Ok(())
}

/// One `\n`-terminated line collected from chunks of input, keeping at
/// most `max_bytes` of it: the limit is enforced as each chunk arrives, so
/// a peer or file that never sends a newline costs `max_bytes`, not its
/// length. Feed it the reader's buffered chunk, consume what it took.
#[derive(Clone, Debug)]
pub struct LineAccumulator {
    bytes: Vec<u8>,
    total: u64,
    too_long: bool,
    done: bool,
    max_bytes: usize,
}

impl LineAccumulator {
    /// An empty line of at most `max_bytes` (newline included).
    pub fn new(max_bytes: usize) -> Self {
        Self {
            bytes: Vec::new(),
            total: 0,
            too_long: false,
            done: false,
            max_bytes,
        }
    }

    /// Starts a new line (keeps the allocation).
    pub fn clear(&mut self) {
        self.bytes.clear();
        self.total = 0;
        self.too_long = false;
        self.done = false;
    }

    /// Takes bytes of `chunk` up to and including the first `\n`; returns
    /// how many were taken (the caller consumes them from its reader).
    /// Bytes past `max_bytes` are counted but not kept ([`Self::too_long`]).
    /// Takes nothing once the line is complete.
    pub fn feed(&mut self, chunk: &[u8]) -> usize {
        if self.done {
            return 0;
        }
        let (take, done) = match chunk.iter().position(|&b| b == b'\n') {
            Some(i) => (i + 1, true),
            None => (chunk.len(), false),
        };
        self.total += take as u64;
        if !self.too_long {
            if self.bytes.len() + take > self.max_bytes {
                self.too_long = true;
                self.bytes = Vec::new();
            } else {
                self.bytes.extend_from_slice(&chunk[..take]);
            }
        }
        self.done = done;
        take
    }

    /// Whether the newline has been taken.
    pub fn is_complete(&self) -> bool {
        self.done
    }

    /// Whether the line is longer than the limit (its bytes are dropped).
    pub fn too_long(&self) -> bool {
        self.too_long
    }

    /// Bytes taken for this line so far, kept or not.
    pub fn total_bytes(&self) -> u64 {
        self.total
    }

    /// The kept bytes (empty when [`Self::too_long`]).
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The limit.
    pub fn max_bytes(&self) -> usize {
        self.max_bytes
    }
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
    let mut acc = LineAccumulator::new(max_bytes);
    acc.bytes = std::mem::take(buf).into_bytes();
    loop {
        let chunk = match reader.fill_buf() {
            Ok(c) => c,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        if chunk.is_empty() {
            break;
        }
        let take = acc.feed(chunk);
        reader.consume(take);
        if acc.is_complete() {
            break;
        }
    }
    if acc.too_long() {
        return Ok(Line::TooLong(acc.total_bytes()));
    }
    if acc.total_bytes() == 0 {
        return Ok(Line::Eof);
    }
    match String::from_utf8(acc.bytes) {
        Ok(s) => {
            *buf = s;
            Ok(Line::Read)
        }
        Err(_) => Ok(Line::NotUtf8),
    }
}

/// Splits one line of a delimited table at `sep` (`"` quotes a field,
/// `""` inside quotes is a quote): the events files and replay tables.
pub fn split_csv_line(line: &str, sep: char) -> Vec<String> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match (c, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', true) => quoted = false,
            ('"', false) if cur.is_empty() => quoted = true,
            (c, false) if c == sep => out.push(std::mem::take(&mut cur)),
            (c, _) => cur.push(c),
        }
    }
    out.push(cur);
    out
}

/// One field for a comma-separated table: quoted (RFC 4180, `"` doubled)
/// when it holds a comma, quote or line break; the writer of the tables
/// [`split_csv_line`] reads (`events.csv`, live and replayed).
pub fn csv_field(s: &str) -> std::borrow::Cow<'_, str> {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\"")).into()
    } else {
        s.into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, Instant};

    #[test]
    fn csv_fields_read_back_whole() {
        for text in ["plain", "a,b", "say \"hi\"", "two\nlines", ""] {
            let line = format!("{},{}", csv_field(text), csv_field("x"));
            assert_eq!(split_csv_line(&line, ','), [text, "x"], "{line}");
        }
        assert_eq!(csv_field("a,b"), "\"a,b\"");
    }

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

    #[test]
    fn accumulator_stops_keeping_at_the_limit_while_reading() {
        // 1 MB without a newline, fed in 4 KiB chunks: never more than the
        // limit kept, every byte counted, complete only at the newline.
        let mut acc = LineAccumulator::new(8192);
        let chunk = [b'x'; 4096];
        for k in 1..=256u64 {
            assert_eq!(acc.feed(&chunk), 4096);
            assert!(acc.bytes().len() <= 8192);
            assert_eq!(acc.too_long(), k * 4096 > 8192);
            assert!(!acc.is_complete());
        }
        assert_eq!(acc.total_bytes(), 1 << 20);
        assert_eq!(acc.feed(b"yz\nnext"), 3);
        assert!(acc.is_complete() && acc.too_long());
        assert_eq!(acc.feed(b"next"), 0, "nothing past the newline");
        acc.clear();
        assert_eq!(acc.feed(b"<ACK ID=\"X\" />\r\nrest"), 16);
        assert_eq!(acc.bytes(), b"<ACK ID=\"X\" />\r\n");
        assert!(acc.is_complete() && !acc.too_long());
    }

    /// The render config of `crates/gazelight/src/config.rs`'s doc comment.
    const RENDER_CONFIG: &str = r#"
# a comment, with, commas, [brackets] and = signs
[scene]
luminance_scale = { kind = "cd_m2_per_unit", factor = 1.0 }
view = { yaw_deg = -78.0, pitch_deg = -4.0, hfov_deg = 90.0, width = 720, height = 800 }

[pipeline]
pooling = { model = "gaussian", sigma_deg = 2.0 }
temporal = { model = "krawczyk", tau_rod_secs = 0.4, tau_cone_secs = 0.1 }
glare = { window_px = 256 }
"#;

    #[test]
    fn config_structure_counts_values_outside_strings_and_comments() {
        check_config_structure(RENDER_CONFIG, ConfigSyntax::Toml).unwrap();
        // Separators inside every kind of string and in comments are text.
        let commas = ",[{=.".repeat(4000);
        for text in [
            format!("a = \"{commas}\\\"{commas}\"\n"),
            format!("a = '{commas}'\n"),
            format!("a = \"\"\"\n{commas}\n\"{commas}\"\"\"\n"),
            format!("a = '''{commas}\n'{commas}'''\n"),
            format!("# {commas}\na = 1\n"),
        ] {
            check_config_structure(&text, ConfigSyntax::Toml).unwrap();
        }
        check_config_structure(
            &format!("{{\"d\": \"{commas}\\\"{commas}\", \"n\": 1}}"),
            ConfigSyntax::Json,
        )
        .unwrap();
    }

    #[test]
    fn config_structure_refuses_long_arrays_and_deep_nesting() {
        let array = format!("a = [{}0]\n", "0,".repeat(MAX_CONFIG_VALUES));
        let e = check_config_structure(&array, ConfigSyntax::Toml).unwrap_err();
        assert!(e.to_string().contains("values"), "{e}");
        // Just under the limit passes.
        let ok = format!("a = [{}0]\n", "0,".repeat(MAX_CONFIG_VALUES - 10));
        check_config_structure(&ok, ConfigSyntax::Toml).unwrap();
        let json = format!("{{\"a\": [{}0]}}", "0,".repeat(MAX_CONFIG_VALUES));
        let e = check_config_structure(&json, ConfigSyntax::Json).unwrap_err();
        assert!(e.to_string().contains("values"), "{e}");
        // Many tables (each `[t]` header counts).
        let tables: String = (0..=MAX_CONFIG_VALUES)
            .map(|k| format!("[t{k}]\n"))
            .collect();
        assert!(check_config_structure(&tables, ConfigSyntax::Toml).is_err());

        let deep = format!("a = {}{}\n", "[".repeat(40), "]".repeat(40));
        let e = check_config_structure(&deep, ConfigSyntax::Toml).unwrap_err();
        assert!(e.to_string().contains("deeper"), "{e}");
        let dotted = format!("{} = 1\n", vec!["k"; 40].join("."));
        assert!(check_config_structure(&dotted, ConfigSyntax::Toml).is_err());
        let deep_json = format!("{}{}", "[".repeat(40), "]".repeat(40));
        assert!(check_config_structure(&deep_json, ConfigSyntax::Json).is_err());
        // 30 levels pass.
        let ok = format!("a = {}{}\n", "[".repeat(30), "]".repeat(30));
        check_config_structure(&ok, ConfigSyntax::Toml).unwrap();
    }

    #[test]
    fn read_config_refuses_a_large_file_by_its_size() {
        let d = tmp("config-size");
        let p = d.join("big.toml");
        std::fs::write(&p, vec![b' '; MAX_CONFIG_BYTES as usize + 1]).unwrap();
        let e = read_config(&p, ConfigSyntax::Toml).unwrap_err();
        assert!(e.to_string().contains("limit"), "{e}");
        let p = d.join("ok.toml");
        std::fs::write(&p, RENDER_CONFIG).unwrap();
        assert_eq!(read_config(&p, ConfigSyntax::Toml).unwrap(), RENDER_CONFIG);
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn expansion_is_capped_at_its_ratio_while_reading() {
        // An endless source of zeros behind a "compressed file" of 1 MiB:
        // 64 MiB come out, then an error; nothing past one byte is kept.
        let mut r = ExpansionLimit::new(io::repeat(0), 1 << 20);
        let mut sink = [0u8; 1 << 16];
        let mut total = 0u64;
        let err = loop {
            match r.read(&mut sink) {
                Ok(0) => panic!("an endless reader ended"),
                Ok(n) => total += n as u64,
                Err(e) => break e,
            }
        };
        assert_eq!(total, 64 << 20);
        assert!(err.to_string().contains("1048576 bytes"), "{err}");
        // A small file may always expand to the floor.
        assert_eq!(
            ExpansionLimit::<io::Empty>::limit_for(10),
            MIN_EXPANSION_BYTES
        );
        let mut small = ExpansionLimit::new(io::repeat(1).take(1000), 10);
        let mut v = Vec::new();
        small.read_to_end(&mut v).unwrap();
        assert_eq!(v.len(), 1000);
    }
}
