//! `[downloads]`: how much work readers of a scan's files may make the daemon do
//! (docs/ARCHITECTURE.md, "Limits and access").

use serde::Deserialize;

/// Caps on the file, archive and thumbnail routes.
#[derive(Debug, Clone, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DownloadsConfig {
    /// Archives written at once; another gets 503 with `Retry-After`.
    pub max_archives: usize,
    /// Seconds a download may wait for its client to read before it is cut.
    pub stall_timeout_s: f64,
    /// Thumbnails decoded at once.
    pub max_thumbnail_decodes: usize,
    /// Seconds a thumbnail request waits for a decode to be free before its 503.
    pub thumbnail_wait_s: f64,
}

impl Default for DownloadsConfig {
    fn default() -> Self {
        Self {
            max_archives: 4,
            stall_timeout_s: 30.0,
            max_thumbnail_decodes: 2,
            thumbnail_wait_s: 5.0,
        }
    }
}

impl DownloadsConfig {
    /// Errors naming the key whose value is out of range.
    pub fn check(&self) -> anyhow::Result<()> {
        for (key, value) in [
            ("downloads.max_archives", self.max_archives),
            (
                "downloads.max_thumbnail_decodes",
                self.max_thumbnail_decodes,
            ),
        ] {
            anyhow::ensure!(value >= 1, "{key} must be at least 1");
        }
        for (key, value) in [
            ("downloads.stall_timeout_s", self.stall_timeout_s),
            ("downloads.thumbnail_wait_s", self.thumbnail_wait_s),
        ] {
            anyhow::ensure!(
                value.is_finite() && value > 0.0 && value <= 3600.0,
                "{key} must be a positive number of seconds (at most an hour), got {value}"
            );
        }
        Ok(())
    }
}
