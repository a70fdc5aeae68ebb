//! isostream-measure: see ARCHITECTURE.md.
#![deny(unsafe_code)]
