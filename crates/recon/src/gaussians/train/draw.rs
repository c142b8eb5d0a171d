//! Which training views one step fits ([`ViewsPerStep`]): drawn from the current pass over the
//! views, one, or one of every channel on a scan whose views measure different channels.

use crate::gaussians::config::ViewsPerStep;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// The training views of one step ([`ViewsPerStep`]) among `n`, drawn from the current pass
/// `order` (views are taken from its end; a new pass of all `n`, shuffled with `rng`, when it is
/// empty): the next view, and with `cover` then, while some of the `total` columns has not been
/// drawn, the next view of the pass that measures one of them (`columns(i)`: view i's columns,
/// None for all), until none is left in the pass (a column no view measures holds no step up).
/// The views passed over stay in the pass for the next steps, so a pass still holds every view
/// once; on an interleaved scan of C channels a step holds one view of each.
pub(super) fn draw_views<'c>(
    order: &mut Vec<usize>,
    rng: &mut ChaCha8Rng,
    n: usize,
    columns: impl Fn(usize) -> Option<&'c [usize]>,
    total: usize,
    mode: ViewsPerStep,
) -> Vec<usize> {
    if order.is_empty() {
        *order = (0..n).collect();
        order.shuffle(rng);
    }
    let mut missing = vec![true; total];
    let mut batch = Vec::with_capacity(1);
    let fills = |i: usize, missing: &[bool]| match columns(i) {
        Some(c) => c.iter().any(|&c| missing[c]),
        None => true,
    };
    while let Some(at) = order
        .iter()
        .rposition(|&i| batch.is_empty() || fills(i, &missing))
    {
        let i = order.remove(at);
        batch.push(i);
        match columns(i) {
            Some(c) => c.iter().for_each(|&c| missing[c] = false),
            None => missing.fill(false),
        }
        if mode == ViewsPerStep::One || !missing.contains(&true) {
            break;
        }
    }
    batch
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Every step of `passes` passes over `n` views of `columns` (None: all `total`).
    fn steps(
        n: usize,
        columns: &[Option<Vec<usize>>],
        total: usize,
        mode: ViewsPerStep,
        passes: usize,
    ) -> Vec<Vec<usize>> {
        let (mut order, mut rng) = (Vec::new(), ChaCha8Rng::seed_from_u64(7));
        let mut out = Vec::new();
        let mut drawn = 0;
        while drawn < passes * n {
            let b = draw_views(
                &mut order,
                &mut rng,
                n,
                |i| columns[i].as_deref(),
                total,
                mode,
            );
            drawn += b.len();
            out.push(b);
        }
        assert_eq!(drawn, passes * n, "steps never straddle two passes");
        out
    }

    #[test]
    fn a_shared_acquisition_draws_one_view_per_step_in_the_upstream_order() {
        // Every view measures every column: `cover` is `one`, and both are the single-view rule
        // (pop from a pass shuffled by the stage's stream), so shared scans train as before.
        let n = 11;
        let all = vec![None; n];
        let cover = steps(n, &all, 3, ViewsPerStep::Cover, 3);
        let one = steps(n, &all, 3, ViewsPerStep::One, 3);
        assert_eq!(cover, one);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut upstream = Vec::new();
        for _ in 0..3 {
            let mut order: Vec<usize> = (0..n).collect();
            order.shuffle(&mut rng);
            upstream.extend(order.into_iter().rev().map(|i| vec![i]));
        }
        assert_eq!(cover, upstream);
    }

    #[test]
    fn an_interleaved_scan_draws_views_until_every_channel_is_fitted() {
        // Channel c at the views v ≡ c (mod 3); channel 3 is measured nowhere and must not
        // hold a step up.
        let n = 12;
        let columns: Vec<_> = (0..n).map(|v| Some(vec![v % 3])).collect();
        let batches = steps(n, &columns, 4, ViewsPerStep::Cover, 4);
        // One view of each channel per step until a pass runs short of some channel: with four
        // views of each per pass, every step of a pass fits all three.
        for b in &batches {
            let mut ch: Vec<usize> = b.iter().map(|v| v % 3).collect();
            ch.sort();
            assert_eq!(ch, [0, 1, 2], "{b:?}");
        }
        assert_eq!(batches.len(), 4 * 4);
        // Each pass holds every view once.
        let mut drawn = 0;
        let mut pass: Vec<usize> = Vec::new();
        for b in &batches {
            pass.extend(b);
            drawn += b.len();
            if drawn % n == 0 {
                pass.sort();
                assert_eq!(pass, (0..n).collect::<Vec<_>>());
                pass.clear();
            }
        }
        // `one` keeps single views on the same scan.
        let one = steps(n, &columns, 4, ViewsPerStep::One, 2);
        assert!(one.iter().all(|b| b.len() == 1));
        // Unequal channels (7 views of channel 0, 3 of channel 1): three steps of a pass pair
        // the channels, the other four fit channel 0 alone.
        let columns: Vec<_> = (0..10).map(|v| Some(vec![usize::from(v >= 7)])).collect();
        let batches = steps(10, &columns, 2, ViewsPerStep::Cover, 2);
        assert_eq!(batches.len(), 2 * 7);
        let pairs = batches.iter().filter(|b| b.len() == 2).count();
        assert_eq!(pairs, 2 * 3);
        assert!(
            batches
                .iter()
                .all(|b| b.len() == 1 || (b[0] < 7) != (b[1] < 7))
        );
    }
}
