//! GRBL 1.1 `error:N` and `ALARM:N` codes and what they mean.

/// Meaning of GRBL 1.1's `error:N` reply (the line was rejected, nothing moved).
pub fn error_meaning(code: u32) -> &'static str {
    match code {
        1 => "G-code word without a letter",
        2 => "bad or missing numeric value",
        3 => "unsupported '$' system command",
        4 => "negative value where a positive one is expected",
        5 => "homing cycle not enabled in settings",
        6 => "step pulse must be longer than 3 microseconds",
        7 => "EEPROM read failed, settings restored to defaults",
        8 => "'$' command needs the controller idle",
        9 => "G-code locked out during alarm or jog",
        10 => "soft limits need homing enabled",
        11 => "line too long, not executed",
        12 => "setting exceeds the maximum step rate",
        13 => "safety door open",
        14 => "build info or startup line too long for EEPROM",
        15 => "jog target exceeds machine travel",
        16 => "invalid jog command",
        17 => "laser mode needs PWM output",
        20 => "unsupported or invalid G-code command",
        21 => "two G-code commands of one modal group in a block",
        22 => "feed rate not set",
        23 => "G-code command needs an integer value",
        24 => "two G-code commands in a block both need axis words",
        25 => "G-code word repeated in a block",
        26 => "G-code command needs axis words, none given",
        27 => "line number out of range",
        28 => "G-code command misses a P or L word",
        29 => "unsupported work coordinate system",
        30 => "G53 needs G0 or G1 motion mode",
        31 => "unused axis words with G80 active",
        32 => "arc without axis words in the selected plane",
        33 => "invalid motion target",
        34 => "arc radius geometry error",
        35 => "arc offset missing its IJK word",
        36 => "unused G-code words left in the block",
        37 => "tool length offset on an axis other than the configured one",
        38 => "tool number too large",
        _ => "unknown error code",
    }
}

/// Meaning of GRBL 1.1's `ALARM:N` (the controller locked itself out).
pub fn alarm_meaning(code: u32) -> &'static str {
    match code {
        1 => "hard limit triggered: position lost, re-home",
        2 => "motion target exceeds machine travel (soft limit)",
        3 => "reset while in motion: position lost, re-home",
        4 => "probe fail: probe not in the expected initial state",
        5 => "probe fail: probe did not contact within travel",
        6 => "homing fail: reset during the homing cycle",
        7 => "homing fail: safety door opened during homing",
        8 => "homing fail: pull-off did not clear the limit switch",
        9 => "homing fail: limit switch not found within search distance",
        10 => "homing fail: second limit switch not found (dual axis)",
        _ => "unknown alarm code",
    }
}

/// Whether `ALARM:code` is a homing failure (ALARM:6–10).
pub fn is_homing_alarm(code: u32) -> bool {
    (6..=10).contains(&code)
}

/// What to check after a homing failure (`ALARM:code`).
pub fn homing_advice(code: u32) -> &'static str {
    match code {
        6 => "the cycle was interrupted by a reset; home again",
        7 => "close the safety door and home again",
        8 => {
            "the switch stayed pressed after the pull-off: set $27 (pull-off, factory 1.000) \
              to a distance that clears the switch, and check the switch is not stuck"
        }
        9 => {
            "no switch was found within 1.5 × max travel: check the switch wiring, \
              $23 (homing direction), $130 (max travel), and that the firmware's homing \
              cycles include only wired axes (stock GRBL homes Z first)"
        }
        10 => "the second switch of a dual axis was not found: check its wiring",
        _ => "check the limit switches and the homing settings ($22–$27)",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_codes_have_distinct_meanings() {
        assert!(error_meaning(9).contains("alarm"));
        assert!(error_meaning(5).contains("homing"));
        assert!(alarm_meaning(1).contains("hard limit"));
        assert!(alarm_meaning(3).contains("reset while in motion"));
        assert!(alarm_meaning(9).contains("limit switch not found"));
        assert!(is_homing_alarm(8) && !is_homing_alarm(3));
        assert!(homing_advice(8).contains("$27"));
        assert!(homing_advice(9).contains("Z first"));
        let errors: std::collections::HashSet<_> = (1..=38)
            .filter(|c| !(18..=19).contains(c))
            .map(error_meaning)
            .collect();
        assert_eq!(errors.len(), 36);
        assert!(!errors.contains("unknown error code"));
    }

    #[test]
    fn unknown_codes_say_so() {
        assert_eq!(error_meaning(0), "unknown error code");
        assert_eq!(error_meaning(99), "unknown error code");
        assert_eq!(alarm_meaning(42), "unknown alarm code");
    }
}
