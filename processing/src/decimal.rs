//! f64 as text the way Rust's `Display` writes it (the shortest digits that read back to
//! the same value, in positional notation: `31`, `-0.00006961825537173412`), from the
//! `ryu` crate's digits, which it finds several times faster. Where two shortest digit
//! strings are equally near the value (a tie: the value's exact decimal expansion ends
//! in a 5 just past them, as 1658206780088562.25; about 3 in 10,000 random bit patterns)
//! ryu takes the even one and `Display` may take the other; both read back to the value.
//! Samples CSV files are written so.

use std::io::Write as _;

/// Appends `v` to `text` as `write!(text, "{v}")` would (but for ties, see above).
pub(crate) fn push(text: &mut Vec<u8>, v: f64) {
    if !v.is_finite() {
        let _ = write!(text, "{v}");
        return;
    }
    let mut buffer = ryu::Buffer::new();
    let shortest = buffer.format_finite(v);
    // ryu writes positional notation for 1e-5 ≤ |v| < 1e16, with `.0` on integers.
    let Some(e) = shortest.bytes().position(|b| b == b'e') else {
        text.extend_from_slice(shortest.strip_suffix(".0").unwrap_or(shortest).as_bytes());
        return;
    };
    let (mantissa, exponent) = (
        &shortest[..e],
        shortest[e + 1..].parse::<i32>().unwrap_or(0),
    );
    let (sign, mantissa) = match mantissa.strip_prefix('-') {
        Some(rest) => ("-", rest),
        None => ("", mantissa),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    // The digits (at most 17, from ryu) without leading or trailing zeros, and where the
    // point falls in them.
    let mut all = [0u8; 40];
    let count = int.len() + frac.len();
    all[..int.len()].copy_from_slice(int.as_bytes());
    all[int.len()..count].copy_from_slice(frac.as_bytes());
    let leading = all[..count].iter().take_while(|&&d| d == b'0').count();
    let end = count
        - all[leading..count]
            .iter()
            .rev()
            .take_while(|&&d| d == b'0')
            .count();
    text.extend_from_slice(sign.as_bytes());
    if leading >= end {
        text.push(b'0');
        return;
    }
    positional(
        text,
        &all[leading..end],
        int.len() as i32 + exponent - leading as i32,
    );
}

/// Appends `digits` (no leading or trailing zeros) with the decimal point after the first
/// `point` of them (before them, or past them, padded with zeros): `Display`'s layout.
fn positional(text: &mut Vec<u8>, digits: &[u8], point: i32) {
    let len = digits.len() as i32;
    if point <= 0 {
        text.extend_from_slice(b"0.");
        text.resize(text.len() + (-point) as usize, b'0');
        text.extend_from_slice(digits);
    } else if point >= len {
        text.extend_from_slice(digits);
        text.resize(text.len() + (point - len) as usize, b'0');
    } else {
        let (whole, fraction) = digits.split_at(point as usize);
        text.extend_from_slice(whole);
        text.push(b'.');
        text.extend_from_slice(fraction);
    }
}

/// Exact powers of ten, 10⁰ … 10²² (every one an f64 without rounding).
const POWERS_OF_TEN: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// |v| rounded to `significant` significant digits (1 ≤ `significant` ≤ 15), halves
/// up, as n · 10^−shift with n an integer (at most `significant` + 1 digits) and the
/// exact power 10^|shift|; `None` for 0, non-finite values and rounding steps beyond
/// 10^±22, which are no exact f64.
fn rounded_digits(v: f64, significant: i32) -> Option<(u64, i32, f64)> {
    if v == 0.0 || !v.is_finite() {
        return None;
    }
    let shift = significant - 1 - leading_exponent(v.abs());
    let &p = POWERS_OF_TEN.get(shift.unsigned_abs() as usize)?;
    let scaled = if shift >= 0 { v.abs() * p } else { v.abs() / p };
    Some(((scaled + 0.5) as u64, shift, p))
}

/// Appends `v` rounded to `significant` significant digits (1 ≤ `significant` ≤ 15) in
/// [`push`]'s layout, the rounded decimal itself: `0.0169687` for 0.01696870136943567 at
/// 6. Values whose rounding step is not an exact power of ten in f64 (beyond 10^±22) are
/// written whole.
pub(crate) fn push_rounded(text: &mut Vec<u8>, v: f64, significant: i32) {
    let Some((mut n, mut shift, _)) = rounded_digits(v, significant) else {
        push(text, v);
        return;
    };
    if n == 0 {
        text.push(b'0');
        return;
    }
    while n.is_multiple_of(10) {
        n /= 10;
        shift -= 1;
    }
    let mut buffer = [0u8; 20];
    let mut start = buffer.len();
    while n > 0 {
        start -= 1;
        buffer[start] = b'0' + (n % 10) as u8;
        n /= 10;
    }
    let digits = &buffer[start..];
    if v < 0.0 {
        text.push(b'-');
    }
    positional(text, digits, digits.len() as i32 - shift);
}

/// `v` rounded to `significant` significant digits (1 ≤ `significant` ≤ 15): the f64
/// nearest the decimal [`push_rounded`] writes, which reads back as itself. Values it
/// writes whole are returned as they are.
pub(crate) fn rounded(v: f64, significant: i32) -> f64 {
    match rounded_digits(v, significant) {
        // n / 10^k and n · 10^k of an integer n < 2^53 and an exact power are correctly
        // rounded.
        Some((n, shift, p)) => {
            let magnitude = if shift >= 0 {
                n as f64 / p
            } else {
                n as f64 * p
            };
            magnitude.copysign(v)
        }
        None => v,
    }
}

/// ⌊log10 a⌋ for a finite a > 0 (one less for a within rounding of a power of ten
/// beyond 10^±22), from a's binary exponent.
fn leading_exponent(a: f64) -> i32 {
    let binary = ((a.to_bits() >> 52) & 0x7ff) as i32 - 1023;
    // ⌊binary · log10 2⌋ (78913 / 2^18 = 0.301029...): ⌊log10 a⌋ or one less.
    let estimate = (binary * 78913) >> 18;
    let next = estimate + 1;
    let power = match POWERS_OF_TEN.get(next.unsigned_abs() as usize) {
        Some(&p) if next >= 0 => p,
        Some(&p) => 1.0 / p,
        None => return estimate,
    };
    if a >= power {
        next
    } else {
        estimate
    }
}

/// A value in a message, to at most six significant digits (`BRIEF_DIGITS`): plain where that
/// is short (0, or 1e-4 ≤ |v| < 1e7), else in scientific notation (`2.22507e-308`, not
/// 308 digits or 17). A value a user wrote with fewer digits reads as written.
pub struct Brief(pub f64);

/// Significant digits of a [`Brief`] value.
const BRIEF_DIGITS: usize = 6;

impl std::fmt::Display for Brief {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = self.0;
        if !v.is_finite() || v == 0.0 {
            return write!(f, "{v}");
        }
        // Scientific to the digits kept, trailing zeros of the mantissa dropped.
        let scientific = format!("{:.*e}", BRIEF_DIGITS - 1, v);
        let (mantissa, exponent) = scientific.split_once('e').unwrap_or((&scientific, "0"));
        let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
        if (1e-4..1e7).contains(&v.abs()) {
            // The same digits, plain: parsed back and written shortest.
            let plain: f64 = format!("{mantissa}e{exponent}").parse().unwrap_or(v);
            write!(f, "{plain}")
        } else {
            write!(f, "{mantissa}e{exponent}")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `push` writes `v` as `Display` does; or, on a tie, as many characters that read
    /// back to `v`, differing only in the last digit. Returns whether it was a tie.
    fn same_as_display(v: f64) -> bool {
        let mut bytes = Vec::new();
        push(&mut bytes, v);
        let text = String::from_utf8(bytes).expect("ASCII");
        let display = format!("{v}");
        if text == display {
            return false;
        }
        let bits = v.to_bits();
        assert_eq!(
            text.len(),
            display.len(),
            "bits {bits:#x}: {text} {display}"
        );
        assert_eq!(
            text[..text.len() - 1],
            display[..display.len() - 1],
            "bits {bits:#x}"
        );
        assert_eq!(text.parse::<f64>().ok(), Some(v), "bits {bits:#x}: {text}");
        true
    }

    #[test]
    fn writes_what_display_writes() {
        for v in [
            0.0,
            -0.0,
            1.0,
            -1.0,
            31.0,
            0.1,
            100.0,
            1e-7,
            1.5e16,
            1e22,
            123.456,
            -45.0,
            0.00006961825537173412,
            f64::MIN_POSITIVE,
            5e-324,
            f64::MAX,
            -f64::MAX,
            1e15,
            1e16,
            1e-5,
            1e-4,
            9.999999999999999e-5,
            f64::NAN,
            f64::INFINITY,
            -f64::INFINITY,
        ] {
            assert!(!same_as_display(v), "{v}");
        }
        // Random bit patterns (every exponent), and values of the size samples hold.
        // Ties are rare, and none among values of the size samples hold.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut ties = 0;
        for _ in 0..200_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ties += usize::from(same_as_display(f64::from_bits(state)));
            let unit = (state >> 11) as f64 / (1u64 << 53) as f64;
            assert!(!same_as_display((unit - 0.5) * 200.0));
            assert!(!same_as_display(unit * 1e-6));
        }
        assert!(ties < 200, "{ties} ties");
    }

    #[test]
    fn leading_exponent_is_that_of_the_leading_digit() {
        for k in -22..=22 {
            let p = 10f64.powi(k);
            assert_eq!(leading_exponent(p), k, "{p}");
            assert_eq!(leading_exponent(p * 1.000001), k, "{p}");
            assert_eq!(leading_exponent(p * 0.999999), k - 1, "{p}");
            assert_eq!(leading_exponent(p * 9.99999), k, "{p}");
        }
    }

    /// `push_rounded` keeps at most the digits asked for and stays within half a unit of
    /// the last one; zero, non-finite and out-of-range values are written whole.
    #[test]
    fn rounded_values_keep_their_significant_digits() {
        let written = |v: f64| {
            let mut bytes = Vec::new();
            push_rounded(&mut bytes, v, 6);
            String::from_utf8(bytes).expect("ASCII")
        };
        assert_eq!(written(0.01696870136943567), "0.0169687");
        assert_eq!(written(-276.12345678), "-276.123");
        assert_eq!(written(9.9999996), "10");
        assert_eq!(written(123456789.0), "123457000");
        assert_eq!(written(0.0), "0");
        assert_eq!(written(1e-300), "0.".to_string() + &"0".repeat(299) + "1");
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        for _ in 0..200_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let unit = (state >> 11) as f64 / (1u64 << 53) as f64;
            let v = (unit - 0.5) * 10f64.powi((state % 30) as i32 - 15);
            if v.abs() < 1e-16 {
                continue; // its rounding step, below 10⁻²², is no exact f64: written whole
            }
            let text = written(v);
            let back: f64 = text.parse().unwrap();
            assert!((back - v).abs() <= 5e-6 * v.abs(), "{v} {text}");
            // `rounded` is the value read back, and is written the same.
            assert_eq!(rounded(v, 6), back, "{v} {text}");
            assert_eq!(written(back), text);
            let digits = text.trim_start_matches(['-', '0', '.']).replace('.', "");
            assert!(digits.trim_end_matches('0').len() <= 6, "{v} {text}");
        }
    }

    #[test]
    fn values_in_messages_stay_short() {
        assert_eq!(Brief(f64::MIN_POSITIVE).to_string(), "2.22507e-308");
        assert_eq!(Brief(1e308).to_string(), "1e308");
        assert_eq!(Brief(1e300 / 3.0).to_string(), "3.33333e299");
        assert_eq!(Brief(1.0 / 30.0).to_string(), "0.0333333");
        assert_eq!(Brief(95.123456789).to_string(), "95.1235");
        assert_eq!(Brief(5.0).to_string(), "5");
        assert_eq!(Brief(0.01).to_string(), "0.01");
        assert_eq!(Brief(-250.5).to_string(), "-250.5");
        assert_eq!(Brief(0.0).to_string(), "0");
    }
}
