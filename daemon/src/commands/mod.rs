//! One module per `gonio` subcommand: its arguments and its `run`.
#![doc = include_str!("../commands.md")]

pub mod calibrate;
pub mod colour;
pub mod compare;
pub mod decode_worker;
pub mod emulate_arm;
pub mod export;
pub mod extract;
pub mod fit;
pub mod hdr;
mod output;
mod plan_check;
pub mod report;
pub mod serve;
pub mod simulate;
pub mod study;
pub mod tradeoff;
