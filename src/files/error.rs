//! Why a file cannot be read, decoded, encoded or written. Every message names the file first
//! (as the user spelled it) and then the problem and, where there is one, the fix.

use std::io;

#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{path}: cannot open: {error}")]
    Open { path: String, error: io::Error },
    #[error("{path}: cannot read: {error}")]
    Read { path: String, error: io::Error },
    /// A read that failed before decoding began; the cause follows in the chain.
    #[error("{path}: cannot read")]
    ReadFile {
        path: String,
        #[source]
        error: io::Error,
    },
    #[error("{path}: not a JPEG, PNG or TIFF image")]
    NotAnImage { path: String },
    #[error(
        "{path}: BigTIFF (64-bit offsets) is not supported; save the frame as a TIFF, PNG or JPEG"
    )]
    BigTiff { path: String },
    #[error("{path}: corrupt or truncated image: {reason}")]
    Truncated { path: String, reason: String },
    #[error("{path}: corrupt or unsupported image: {reason}")]
    Unsupported { path: String, reason: String },
    #[error("{path}: {width}x{height} is larger than the {limit}-pixel limit")]
    TooLarge {
        path: String,
        width: u32,
        height: u32,
        limit: u64,
    },
    /// Floating-point samples have no white point: values above 1.0 would clip to white.
    #[error(
        "{path}: {color:?} samples (32-bit floating point) are not supported; convert the \
         stack to 16-bit integer TIFF or PNG with one scale for every frame"
    )]
    FloatSamples {
        path: String,
        color: image::ColorType,
    },
    /// A multipage TIFF's first page is often a thumbnail: fusing it silently would be wrong.
    #[error(
        "{path}: a multipage TIFF; focusd fuses single images: save the page you mean as a \
         file of its own"
    )]
    Multipage { path: String },
    #[error("{path}: unknown output extension {ext:?}; use .jpg, .png or .tif")]
    UnknownExtension { path: String, ext: String },
    #[error("a JPEG holds 1 to 65535 pixels a side, not {width}x{height}: write .png or .tif")]
    JpegSize { width: usize, height: usize },
    #[error(transparent)]
    Encode(#[from] image::ImageError),
    #[error("cannot encode a DNG: {0}")]
    Dng(#[from] tiff::TiffError),
    #[error(transparent)]
    Jpeg(#[from] jpeg_encoder::EncodingError),
    #[error("{path}: not a file path")]
    NotAFilePath { path: String },
    #[error("{path}: cannot write: {error}")]
    Write { path: String, error: io::Error },
    #[error("{path}: not an output checked before the work")]
    NotChecked { path: String },
    #[error("{path}: output directory {dir} does not exist")]
    NoDirectory { path: String, dir: String },
    #[error("{path}: is a directory; name an output file")]
    IsADirectory { path: String },
    #[error("{path}: is the input {input}; name another output file")]
    IsAnInput { path: String, input: String },
    #[error("{path}: is the same file as the output {other}")]
    SameFile { path: String, other: String },
    #[error("{path}: nothing was written to it")]
    NothingWritten { path: String },
}

/// A path as messages show it.
pub(crate) fn shown(path: &std::path::Path) -> String {
    path.display().to_string()
}
