//! Panics turned into errors at the boundary of untrusted work (decoding a hostile
//! file, one processing step of the daemon): [`catch`] runs a closure and returns the
//! panic's message as an error instead of unwinding further. While a closure runs under
//! [`catch`], the hook of [`install_quiet_panic_hook`] prints nothing, so a caught
//! panic (ours, or one a third-party decoder catches itself) never reaches stderr.
//! [`one_line`] keeps such messages, and any error a user sees, on one line.

use std::cell::Cell;
use std::panic::{self, AssertUnwindSafe};
use std::sync::Once;

thread_local! {
    /// Depth of [`catch`] calls on this thread.
    static GUARDED: Cell<u32> = const { Cell::new(0) };
}

/// Runs `f`; a panic inside it becomes `Err(message)`. Nothing `f` touched may be
/// used afterwards unless it stays consistent through a panic (values built inside `f`
/// are dropped with it).
pub fn catch<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    GUARDED.with(|depth| depth.set(depth.get() + 1));
    let result = panic::catch_unwind(AssertUnwindSafe(f));
    GUARDED.with(|depth| depth.set(depth.get().saturating_sub(1)));
    result.map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| one_line(s))
            .or_else(|| payload.downcast_ref::<String>().map(|s| one_line(s)))
            .unwrap_or_else(|| "unknown panic".to_owned())
    })
}

/// `text` on one line: its lines trimmed and joined by a space. Messages of
/// third-party code (a decoder's error, a panic) may span several.
pub fn one_line(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .filter(|line| !line.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Whether the current thread runs inside [`catch`].
pub fn is_guarded() -> bool {
    GUARDED.with(Cell::get) > 0
}

/// Installs (once per process) a panic hook that stays silent inside [`catch`] and
/// defers to the previous hook everywhere else. Binaries call it at start.
pub fn install_quiet_panic_hook() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let previous = panic::take_hook();
        panic::set_hook(Box::new(move |info| {
            if !is_guarded() {
                previous(info);
            }
        }));
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_its_message_and_the_guard_unwinds() {
        install_quiet_panic_hook();
        assert_eq!(catch(|| 7), Ok(7));
        let err = catch(|| -> u8 { panic!("bad header {}", 3) }).unwrap_err();
        assert_eq!(err, "bad header 3");
        assert_eq!(
            catch(|| std::panic::panic_any(5u8)).unwrap_err(),
            "unknown panic"
        );
        assert_eq!(
            catch(|| -> u8 { panic!("Caught a panic.\nPlease file a bug\n") }).unwrap_err(),
            "Caught a panic. Please file a bug"
        );
        let nested = catch(|| catch(|| panic!("inner")).unwrap_err());
        assert_eq!(nested.as_deref(), Ok("inner"));
        assert!(!is_guarded());
    }
}
