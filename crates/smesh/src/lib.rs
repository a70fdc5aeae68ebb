//! isostream-smesh: see ARCHITECTURE.md.
#![deny(unsafe_code)]
