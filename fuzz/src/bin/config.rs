//! The daemon's configuration loader on arbitrary text: nothing may panic;
//! an accepted configuration names a reconstructor it can run.

use dbtor_firmware::config::Config;
use std::path::Path;

fn main() {
    afl::fuzz!(|data: &[u8]| {
        if let Ok(text) = std::str::from_utf8(data) {
            if let Ok(c) = Config::parse(text, Path::new("/nonexistent/dbtor.toml")) {
                assert!(c.recon.reconstructor == "dbtor" || c.recon.reconstructor == "mltr");
            }
        }
    });
}
