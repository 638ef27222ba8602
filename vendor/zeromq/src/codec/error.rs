use thiserror::Error;

/// Represents an error when encoding/decoding raw byte buffers and frames
#[non_exhaustive]
#[derive(Error, Debug)]
pub enum CodecError {
    #[error("{0}")]
    Command(&'static str),
    #[error("{0}")]
    Greeting(&'static str),
    #[error("{0}")]
    Mechanism(&'static str),
    #[error("{0}")]
    Decode(&'static str),
    #[error("{0}")]
    Io(#[from] std::io::Error),
    #[error("{0}")]
    Other(&'static str),
    /// gazelight patch: a frame or multipart message over the socket's
    /// `max_message_size` / `max_message_frames`.
    #[error("peer sent {what} of {size} (limit {limit}); connection closed")]
    MessageTooLarge {
        /// What was over the limit ("a frame header announcing bytes",
        /// "a multipart message of bytes", "a multipart message of frames").
        what: &'static str,
        /// The announced or accumulated size.
        size: u64,
        /// The socket's limit.
        limit: u64,
    },
}

pub(crate) type CodecResult<T> = Result<T, CodecError>;
