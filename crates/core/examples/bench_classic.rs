//! Classic-CT benchmark (see `prism_core::classic::bench`): prints one JSON object.
//!
//! `cargo run --release -p prism-core --example bench_classic [-- --quick] [--no-rtk]
//! [--no-ordering] [--no-256] [--ordering-only]`
//! The RTK side runs with `$PRISM_PYTHON` (default `python3`) when `itk-rtk` is importable.

use prism_core::classic::bench::{BenchOptions, run};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut opts = BenchOptions::default();
    for a in &args {
        match a.as_str() {
            "--quick" => {
                opts = BenchOptions {
                    n: 64,
                    det: 128,
                    full_views: 0,
                    fp_256: false,
                    ordering: false,
                    repeats: 1,
                    ..opts
                };
            }
            "--no-rtk" => opts.python = None,
            "--no-ordering" => opts.ordering = false,
            "--no-256" => opts.fp_256 = false,
            "--ordering-only" => {
                println!("{}", serde_json::to_string_pretty(&prism_core::classic::bench::ordering()?)?);
                return Ok(());
            }
            other => return Err(format!(
                "unknown argument `{other}` (expected --quick, --no-rtk, --no-ordering, --no-256, --ordering-only)"
            )
            .into()),
        }
    }
    println!("{}", serde_json::to_string_pretty(&run(&opts)?)?);
    Ok(())
}
