//! What the firmware's binaries share on their command lines.

/// The error and its causes on one line, each cause once: thiserror messages
/// often embed their source (`"{path}: {source}"`) and expose it as the
/// source as well, so `{:#}` would print it twice; a cause whose text the
/// line already holds is left out.
pub fn error_chain(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !out.contains(&c) {
            out.push_str(": ");
            out.push_str(&c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("spool {path}: {source}")]
    struct Embeds {
        path: String,
        source: std::io::Error,
    }

    #[test]
    fn each_cause_is_printed_once() {
        let io = std::io::Error::new(std::io::ErrorKind::PermissionDenied, "permission denied");
        let e = anyhow::Error::new(Embeds {
            path: "/var/lib/dbtor".into(),
            source: io,
        })
        .context("starting the daemon");
        assert_eq!(
            error_chain(&e),
            "starting the daemon: spool /var/lib/dbtor: permission denied"
        );
        assert_eq!(format!("{e:#}").matches("permission denied").count(), 2);
    }
}
