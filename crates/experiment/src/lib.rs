//! Prism's experiment suites: the paper's evidence by one command.
//!
//! Data flow: a suite file ([`suite`]) → its cells ([`plan`]: every scene at every view count,
//! noise level and seed, every method on each) → run one at a time, resumably ([`execute`];
//! or as a Slurm job array, [`slurm`]) → the finished run directories read back ([`results`],
//! [`curve`]) → `results.csv`, `report.md` and the figures ([`report`], drawn by [`figures`]),
//! and on request `report.html`, a page to browse them with a slice viewer ([`html`]).
//! A cell is an ordinary scene or run directory; nothing here reconstructs or scores by itself
//! (that is `prism-recon`'s pipeline).

pub mod curve;
pub mod error;
pub mod execute;
pub mod figures;
pub mod html;
pub mod plan;
pub mod report;
pub mod results;
pub mod slurm;
pub mod suite;

pub use error::{Error, Result};
pub use plan::Plan;
pub use suite::LoadedSuite;
