//! The channels' gains: each channel's mean line integral over the channels', the ratio of its
//! attenuation to the channel mean (over a full set of views the mean line integral is the
//! object's integrated attenuation). 4D-SG's stage 1 divides by them to start its joint fit
//! from one common image per view, its stage 2 starts its curve model from them, and the
//! classic `tv` method weighs each channel's total variation by their inverse.

use super::Scene;
use ndarray::Axis;

impl Scene {
    /// Each channel's mean line integral over those of `views` at which it was measured,
    /// divided by the mean of these over the channels (1 for a channel with no measured view
    /// or no attenuation).
    pub fn channel_ratios(&self, views: &[usize]) -> Vec<f64> {
        let m = self.n_channels();
        let means: Vec<f64> = (0..m)
            .map(|c| {
                let p = self.channel_projections(c);
                let (sum, n) = views.iter().filter(|&&v| self.availability[[v, c]]).fold(
                    (0.0f64, 0usize),
                    |(s, n), &v| {
                        let img = p.index_axis(Axis(0), v);
                        (
                            s + img.iter().map(|&x| x as f64).sum::<f64>(),
                            n + img.len(),
                        )
                    },
                );
                sum / n.max(1) as f64
            })
            .collect();
        let mean = means.iter().sum::<f64>() / m as f64;
        means
            .iter()
            .map(|&x| if mean > 0.0 && x > 0.0 { x / mean } else { 1.0 })
            .collect()
    }
}
