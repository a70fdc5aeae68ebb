//! isostream-pipeline: see ARCHITECTURE.md.
#![deny(unsafe_code)]
