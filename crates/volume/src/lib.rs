//! isostream-volume: see ARCHITECTURE.md.
#![deny(unsafe_code)]
