//! The camera worker process of `SupervisedCamera`: opens a camera through libgphoto2
//! and answers line-delimited JSON requests on stdin with replies on stdout.
//!
//! Usage: `gonio-camera-worker [--model MODEL] [--port PORT]`.

use std::io;
use std::process::ExitCode;

use gonio_drivers::gphoto2_camera::{GphotoCamera, GphotoConfig};
use gonio_drivers::supervised_camera::serve_worker;

fn main() -> ExitCode {
    let mut config = GphotoConfig::default();
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let slot = match flag.as_str() {
            "--model" => &mut config.model,
            "--port" => &mut config.port,
            _ => {
                eprintln!("gonio-camera-worker: unknown argument {flag:?}; usage: [--model MODEL] [--port PORT]");
                return ExitCode::from(2);
            }
        };
        let Some(value) = args.next() else {
            eprintln!("gonio-camera-worker: {flag} needs a value");
            return ExitCode::from(2);
        };
        *slot = Some(value);
    }
    match serve_worker(
        || GphotoCamera::open(config),
        io::stdin().lock(),
        io::stdout().lock(),
    ) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("gonio-camera-worker: {e}");
            ExitCode::FAILURE
        }
    }
}
