//! Lists of indices into `n` items (a scan's views, a stage's training views): read from files
//! and configs, they must be distinct and in range before anything indexes with them.

/// Why an index list is not a set of distinct indices below `n`: the first bad entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IndexFault {
    /// Entry `at` holds `index`, which is not below `n`.
    Beyond { at: usize, index: usize, n: usize },
    /// Entry `at` repeats `index`.
    Repeated { at: usize, index: usize },
}

impl std::fmt::Display for IndexFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            IndexFault::Beyond { index, n, .. } => write!(f, "{index} is beyond the {n} there are"),
            IndexFault::Repeated { index, .. } => write!(f, "{index} is listed twice"),
        }
    }
}

/// Check that `indices` are distinct and below `n`; the first entry that is not, otherwise.
pub fn distinct_below(indices: &[usize], n: usize) -> Result<(), IndexFault> {
    let mut seen = vec![false; n];
    for (at, &index) in indices.iter().enumerate() {
        if index >= n {
            return Err(IndexFault::Beyond { at, index, n });
        }
        if std::mem::replace(&mut seen[index], true) {
            return Err(IndexFault::Repeated { at, index });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_entry_out_of_range_or_repeated_is_named() {
        assert_eq!(distinct_below(&[2, 0, 1], 3), Ok(()));
        assert_eq!(distinct_below(&[], 0), Ok(()));
        assert_eq!(
            distinct_below(&[0, 3, 1], 3),
            Err(IndexFault::Beyond {
                at: 1,
                index: 3,
                n: 3
            })
        );
        assert_eq!(
            distinct_below(&[1, 0, 1, 9], 3),
            Err(IndexFault::Repeated { at: 2, index: 1 })
        );
    }
}
