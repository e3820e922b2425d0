//! f64 as text the way Rust's `Display` writes it (the shortest digits that read back to
//! the same value, in positional notation: `31`, `-0.00006961825537173412`), from the
//! `ryu` crate's digits, which it finds several times faster. Where two shortest digit
//! strings are equally near the value (a tie: the value's exact decimal expansion ends
//! in a 5 just past them, as 1658206780088562.25; about 3 in 10,000 random bit patterns)
//! ryu takes the even one and `Display` may take the other; both read back to the value.
//! Samples CSV files are written so.

use std::fmt::Write as _;

/// Appends `v` to `text` as `write!(text, "{v}")` would (but for ties, see above).
pub(crate) fn push(text: &mut String, v: f64) {
    if !v.is_finite() {
        let _ = write!(text, "{v}");
        return;
    }
    let mut buffer = ryu::Buffer::new();
    let shortest = buffer.format_finite(v);
    // ryu writes positional notation for 1e-5 ≤ |v| < 1e16, with `.0` on integers.
    let Some(e) = shortest.bytes().position(|b| b == b'e') else {
        text.push_str(shortest.strip_suffix(".0").unwrap_or(shortest));
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
    text.push_str(sign);
    if leading >= end {
        text.push('0');
        return;
    }
    let digits = std::str::from_utf8(&all[leading..end]).unwrap_or("0");
    let point = int.len() as i32 + exponent - leading as i32;
    let len = digits.len() as i32;
    if point <= 0 {
        text.push_str("0.");
        text.extend(std::iter::repeat_n('0', (-point) as usize));
        text.push_str(digits);
    } else if point >= len {
        text.push_str(digits);
        text.extend(std::iter::repeat_n('0', (point - len) as usize));
    } else {
        let (whole, fraction) = digits.split_at(point as usize);
        text.push_str(whole);
        text.push('.');
        text.push_str(fraction);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `push` writes `v` as `Display` does; or, on a tie, as many characters that read
    /// back to `v`, differing only in the last digit. Returns whether it was a tie.
    fn same_as_display(v: f64) -> bool {
        let mut text = String::new();
        push(&mut text, v);
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
}
