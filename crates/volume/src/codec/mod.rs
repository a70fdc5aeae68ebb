//! Byte-stream adapters that turn an encoded payload into plain stored voxels, one `Read` layer
//! each, so every reader composes the same tested pieces (e.g. VTI = base64 -> zlib blocks).

mod ascii;
mod base64;
mod gzip;
mod zblocks;

pub(crate) use ascii::AsciiValues;
pub(crate) use base64::Base64Reader;
pub(crate) use gzip::GzipMembers;
pub(crate) use zblocks::{ZlibBlocks, ZlibLayout};

use std::io;

/// An `InvalidData` error: the stream adapters' way of saying "the encoding is broken here",
/// which the stream source turns into a one-line format error.
pub(crate) fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

#[cfg(test)]
pub(crate) mod tests {
    pub(crate) use super::zblocks::tests::compress;
}
