//! The offline commands of the `gonio` binary, run as a user runs them, one binary (one link).

mod common;

mod colour;
mod emulate_arm;
mod errors;
mod export;
mod fit;
mod fit_auto;
mod goniochromatic;
mod hostile;
mod incomplete_scan;
mod overwrite;
mod readme_commands;
mod simulate;
mod study;
mod terminal;
