//! Sizes before anything is allocated: checked element counts for every shape read from a file
//! or a config, and peak-memory estimates ([`Footprint`]) that a command prints with `--dry-run`
//! and refuses above the memory the machine has available.

use crate::{Error, Result};
use serde::Serialize;

/// The process before any data: code, the allocator's arenas, thread stacks (measured: `prism
/// info` holds 22 MB with a 3.6 MB scene). Every command's estimate starts with it.
pub const PROCESS_BYTES: u64 = 20_000_000;

/// The most elements one array may hold (2⁴⁰: 4 TiB of f32). Larger counts are refused as
/// input errors before any arithmetic on them can overflow.
pub const MAX_ELEMENTS: usize = 1 << 40;

/// The product of `dims`, or an error naming `field` when it overflows or exceeds
/// [`MAX_ELEMENTS`].
pub fn elements(field: &str, dims: &[usize]) -> Result<usize> {
    let shape = dims
        .iter()
        .map(|d| d.to_string())
        .collect::<Vec<_>>()
        .join(" × ");
    match dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)) {
        Some(n) if n <= MAX_ELEMENTS => Ok(n),
        _ => Err(Error::invalid(
            field,
            format!("{shape} elements: more than one array can hold (2^40)"),
        )),
    }
}

/// Bytes of `n` elements of `size` bytes, saturating (estimates only).
pub fn bytes(n: usize, size: usize) -> u64 {
    (n as u64).saturating_mul(size as u64)
}

/// What a computation holds at its peak, item by item (an estimate, in bytes).
///
/// `items` are held for the whole computation. A computation that goes through phases whose
/// buffers never coexist (a run's initialisation, its training, its final scoring) lists each
/// phase's own items under `phases`: the peak is what is held throughout plus the largest phase.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Footprint {
    pub items: Vec<(String, u64)>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub phases: Vec<(String, Vec<(String, u64)>)>,
}

impl Footprint {
    /// An estimate holding only the process itself ([`PROCESS_BYTES`]).
    pub fn process() -> Self {
        let mut f = Footprint::default();
        f.add("the process (code, allocator, threads)", PROCESS_BYTES);
        f
    }

    /// Add an item held throughout.
    pub fn add(&mut self, what: impl Into<String>, bytes: u64) -> &mut Self {
        self.items.push((what.into(), bytes));
        self
    }

    /// Add an item held only during `phase` (the phase is made at its first item).
    pub fn add_in(&mut self, phase: &str, what: impl Into<String>, bytes: u64) -> &mut Self {
        let item = (what.into(), bytes);
        match self.phases.iter_mut().find(|p| p.0 == phase) {
            Some(p) => p.1.push(item),
            None => self.phases.push((phase.to_string(), vec![item])),
        }
        self
    }

    /// The phase holding the most, with its bytes (`None` without phases).
    pub fn largest_phase(&self) -> Option<(&str, u64)> {
        self.phases
            .iter()
            .map(|(name, items)| (name.as_str(), sum(items)))
            .fold(None, |best: Option<(&str, u64)>, p| match best {
                Some(b) if b.1 >= p.1 => Some(b),
                _ => Some(p),
            })
    }

    /// The estimated peak, bytes: what is held throughout plus the largest phase.
    pub fn total(&self) -> u64 {
        sum(&self.items).saturating_add(self.largest_phase().map_or(0, |p| p.1))
    }

    /// One line per item (phases under their names) and the total, for `--dry-run`.
    pub fn describe(&self) -> String {
        let mut s = String::new();
        for (what, b) in &self.items {
            s.push_str(&format!("  {:>10}  {what}\n", human(*b)));
        }
        for (phase, items) in &self.phases {
            s.push_str(&format!("  during {phase} only:\n"));
            for (what, b) in items {
                s.push_str(&format!("    {:>10}  {what}\n", human(*b)));
            }
        }
        s.push_str(&format!("  {:>10}  estimated peak", human(self.total())));
        if let Some((phase, _)) = self.largest_phase() {
            s.push_str(&format!(", during {phase}"));
        }
        if let Some(a) = available() {
            s.push_str(&format!(" ({} available)", human(a)));
        }
        s
    }

    /// Refuse when the estimate exceeds the memory available (unless `allow`); `what` names the
    /// computation in the error.
    pub fn check(&self, what: &str, allow: bool) -> Result<()> {
        match exceeds_available(self.total()) {
            Some(a) if !allow => Err(Error::invalid(
                "memory",
                format!(
                    "{what} needs about {} at its peak (estimate; `--dry-run` itemises it) but \
                     {} is available; make the problem smaller, or pass --allow-memory to run \
                     anyway",
                    human(self.total()),
                    human(a)
                ),
            )),
            _ => Ok(()),
        }
    }
}

fn sum(items: &[(String, u64)]) -> u64 {
    items.iter().fold(0u64, |a, i| a.saturating_add(i.1))
}

/// Memory the kernel says is available for new allocations (`MemAvailable`), bytes; `None`
/// where it cannot be read (no `/proc/meminfo`), in which case nothing is refused.
pub fn available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb.saturating_mul(1024))
}

/// The memory available when `bytes` exceed it (`None` when they fit, or when it cannot be
/// read): every check of a size against the machine goes through here.
pub fn exceeds_available(bytes: u64) -> Option<u64> {
    available().filter(|&a| bytes > a)
}

/// `12.3 MB`, `4.0 GB`, … (decimal units).
pub fn human(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        0..1_000_000 => format!("{:.1} kB", b / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} MB", b / 1e6),
        1_000_000_000..1_000_000_000_000 => format!("{:.1} GB", b / 1e9),
        _ => format!("{:.1} TB", b / 1e12),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn element_counts_overflowing_or_beyond_the_limit_are_refused() {
        assert_eq!(elements("volume", &[64, 64, 64]).unwrap(), 262_144);
        assert_eq!(elements("empty", &[]).unwrap(), 1);
        // 2²² cubed = 2⁶⁶ overflows usize; 10⁵ cubed = 10¹⁵ is below usize::MAX but above 2⁴⁰.
        for dims in [[1 << 22; 3], [100_000; 3]] {
            let e = elements("volume.n", &dims).unwrap_err().to_string();
            assert!(e.contains("volume.n") && e.contains("2^40"), "{e}");
        }
        assert_eq!(elements("x", &[1 << 20, 1 << 20]).unwrap(), MAX_ELEMENTS);
        assert!(elements("x", &[(1 << 20) + 1, 1 << 20]).is_err());
    }

    #[test]
    fn footprints_sum_saturating_and_refuse_beyond_what_is_available() {
        let mut f = Footprint::default();
        f.add("a", 3).add("b", u64::MAX);
        assert_eq!(f.total(), u64::MAX);
        if available().is_some() {
            let e = f.check("the test", false).unwrap_err().to_string();
            assert!(
                e.contains("--allow-memory") && e.contains("the test"),
                "{e}"
            );
        }
        f.check("the test", true).unwrap();
        let mut small = Footprint::default();
        small.add("one kB", 1000);
        small.check("a small job", false).unwrap();
        assert!(small.describe().contains("1.0 kB  one kB"));
    }

    #[test]
    fn phases_that_never_coexist_count_once_at_the_largest() {
        let mut f = Footprint::default();
        f.add("held", 10)
            .add_in("init", "fdk", 30)
            .add_in("training", "gaussians", 25)
            .add_in("training", "images", 15)
            .add_in("scoring", "maps", 35);
        // 10 + max(30, 25 + 15, 35).
        assert_eq!(f.total(), 50);
        assert_eq!(f.largest_phase(), Some(("training", 40)));
        let d = f.describe();
        assert!(d.contains("during training only:"), "{d}");
        assert!(d.contains("estimated peak, during training"), "{d}");
        assert_eq!(Footprint::process().largest_phase(), None);
    }

    #[test]
    fn human_sizes_use_decimal_units() {
        assert_eq!(human(999), "1.0 kB");
        assert_eq!(human(2_500_000), "2.5 MB");
        assert_eq!(human(4_000_000_000), "4.0 GB");
        assert_eq!(human(2_800_000_000_000_000), "2800.0 TB");
    }
}
