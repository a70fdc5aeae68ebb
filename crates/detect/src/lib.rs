//! isostream-detect: see ARCHITECTURE.md.
#![deny(unsafe_code)]
