//! isostream-simplify: see ARCHITECTURE.md.
#![deny(unsafe_code)]
