//! Shared helpers of the end-to-end tests.

use std::process::Command;

/// Run the `prism` binary; returns whether it succeeded and its stdout + stderr.
pub fn prism(args: &[&str]) -> (bool, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_prism"))
        .args(args)
        .output()
        .expect("prism runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    (o.status.success(), text)
}
