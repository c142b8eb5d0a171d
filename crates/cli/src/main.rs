//! `prism`: simulate, inspect and reconstruct sparse-view spectral CT scenes.
fn main() {}
