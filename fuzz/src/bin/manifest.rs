//! A model manifest's parser and checks on arbitrary text: nothing may
//! panic; an accepted manifest has dual/primal block pairs.

use dbt_dbtor::ModelManifest;
use std::path::Path;

fn main() {
    afl::fuzz!(|data: &[u8]| {
        if let Ok(text) = std::str::from_utf8(data) {
            if let Ok(m) = ModelManifest::parse(text, Path::new("manifest.json")) {
                assert!(!m.blocks.is_empty() && m.blocks.len() % 2 == 0);
            }
        }
    });
}
