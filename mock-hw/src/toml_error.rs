//! TOML errors on one line, as every error a user sees is: where, the line at fault
//! and what, instead of the excerpt that `toml` prints over several lines.

/// Longest excerpt of the line at fault quoted, in characters.
const EXCERPT_CHARS: usize = 80;

/// `error`, from parsing `text`, as ``line L, column C (`the line`): message``: the line
/// names the key, which the message alone often does not.
pub fn one_line(text: &str, error: &toml::de::Error) -> String {
    let message = error
        .message()
        .lines()
        .map(str::trim)
        .filter(|line| !line.is_empty())
        .collect::<Vec<_>>()
        .join(" ");
    let Some(before) = error.span().and_then(|span| text.get(..span.start)) else {
        return message;
    };
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().unwrap_or("").chars().count() + 1;
    let source = text.lines().nth(line - 1).unwrap_or("").trim();
    let mut excerpt: String = source.chars().take(EXCERPT_CHARS).collect();
    if excerpt.len() < source.len() {
        excerpt.push('…');
    }
    format!("line {line}, column {column} (`{excerpt}`): {message}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn position_and_message_on_one_line() {
        let text = "time_scale = 1.0\nsteps = [1,,]\n";
        let error = toml::from_str::<toml::Table>(text).unwrap_err();
        assert!(error.to_string().lines().count() > 1, "{error}");
        let line = one_line(text, &error);
        assert!(line.starts_with("line 2, column "), "{line}");
        assert!(line.contains("(`steps = [1,,]`)"), "{line}");
        assert_eq!(line.lines().count(), 1, "{line}");
    }
}
