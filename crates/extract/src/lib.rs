//! isostream-extract: see ARCHITECTURE.md.
#![deny(unsafe_code)]
