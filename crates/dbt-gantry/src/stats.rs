//! What one reception of the projection stream did: the link's counters,
//! kept with the spooled acquisition (its gantry note) and in the logs.

use serde::{Deserialize, Serialize};

/// What a reception did (for the logs and the status file).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LinkStats {
    /// Bytes received.
    pub bytes: usize,
    /// Intact frames.
    pub frames: usize,
    /// Frames rejected by their CRC.
    pub crc_errors: usize,
    /// Frames refused for their declared length.
    pub length_errors: usize,
    /// Sequence numbers asked again.
    pub naks: usize,
    /// Bytes skipped while resynchronising.
    pub garbage_bytes: usize,
    /// Log lines suppressed by the rate limit.
    pub suppressed_logs: usize,
}

impl std::fmt::Display for LinkStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} bytes, {} intact frames, {} CRC errors, {} length errors, {} bytes of garbage",
            self.bytes, self.frames, self.crc_errors, self.length_errors, self.garbage_bytes
        )
    }
}
