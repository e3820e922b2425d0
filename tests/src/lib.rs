//! End-to-end tests across gonio's crates live in `tests/tests/`; this library holds
//! their shared helpers.
