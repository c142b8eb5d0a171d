//! The axis estimators recover a known detector shift on simulated scans (analytic ellipsoid
//! projections). The criterion is a quarter column (#38): both metrics are smooth in the offset
//! and the refinement is parabolic over ¼-column samples, so a correct estimator lands well
//! inside it; a sign error or a missing factor 2 in the conjugate would be off by the shift itself.

use super::axis::*;
use ndarray::{Array2, Axis};
use prism_domain::geometry::{Beam, Geometry};
use prism_domain::import::{AxisConfig, AxisMethod};
use prism_domain::observe::{Observer, Silent};
use prism_domain::scene::{Channel, Provenance, Scene, SpectralCoordinate, Split};
use prism_domain::testing::{analytic_projections, phantom};
use std::f64::consts::PI;
use std::sync::Mutex;

/// The last phase's total and the last progress count.
#[derive(Default)]
struct Counter(Mutex<(u64, u64)>);

impl Observer for Counter {
    fn phase(&self, _name: &str, total: u64) {
        *self.0.lock().unwrap() = (total, 0);
    }
    fn progress(&self, done: u64, _status: &str) {
        self.0.lock().unwrap().1 = done;
    }
}

/// A one-channel scene of the test phantom measured with the detector shifted by `true_px`
/// columns, whose geometry claims no shift.
fn scan(beam: Beam, rows: usize, views: usize, span: f64, true_px: f64) -> Scene {
    let mut g = prism_domain::testing::geometry(beam, 40, 64, views, false);
    g.detector.rows = rows;
    g.detector.pitch_v = g.detector.pitch_u;
    g.volume.nz = rows;
    g.volume.dz = match beam {
        Beam::Parallel => g.detector.pitch_v,
        Beam::Cone => g.detector.pitch_v * g.dso / g.dsd,
    };
    g.angles_rad = Geometry::uniform_angles(views, 0.2, span);
    let mut measured = g.clone();
    measured.detector.offset_u = true_px * g.detector.pitch_u;
    let p = analytic_projections(&measured, &phantom(16.0));
    let mut channels = vec![Channel::new(
        "70keV",
        SpectralCoordinate::Energy { kev: 70.0 },
    )];
    prism_domain::scene::normalise_tau(&mut channels).unwrap();
    Scene {
        name: "axis-test".into(),
        geometry: g,
        channels,
        projections: p.insert_axis(Axis(0)),
        availability: Array2::from_elem((views, 1), true),
        references: None,
        split: Split::all_train(views),
        provenance: Provenance::default(),
        structural: None,
        materials: None,
    }
}

fn estimate(scene: &Scene, method: AxisMethod) -> prism_domain::import::AxisEstimate {
    let config = AxisConfig {
        method,
        range_px: Some(8.0),
    };
    estimate_axis(scene, &config, &Silent).unwrap()
}

#[test]
fn opposing_views_recover_a_shift_in_parallel_and_fan_beams() {
    for (beam, rows, shift) in [(Beam::Parallel, 2, 3.3), (Beam::Cone, 1, -2.6)] {
        let scene = scan(beam, rows, 180, 2.0 * PI, shift);
        let e = estimate(&scene, AxisMethod::Auto);
        assert_eq!(e.method, AxisMethod::Opposing, "{beam:?}: a full turn");
        assert!((e.offset_px - shift).abs() < 0.25, "{beam:?}: {e:?}");
        assert!(
            (e.offset_u - shift * scene.geometry.detector.pitch_u).abs()
                < 1e-9 + 0.25 * scene.geometry.detector.pitch_u
        );
        assert!(
            e.uncertainty_px.is_finite() && e.uncertainty_px < 0.25,
            "{e:?}"
        );
    }
}

#[test]
fn sharpness_recovers_a_shift_on_a_half_turn() {
    let scene = scan(Beam::Parallel, 2, 120, PI, 3.3);
    let e = estimate(&scene, AxisMethod::Auto);
    assert_eq!(
        e.method,
        AxisMethod::Sharpness,
        "half a turn has no conjugates"
    );
    assert!((e.offset_px - 3.3).abs() < 0.25, "{e:?}");
    // Asked for explicitly, opposing views refuse a half turn.
    let config = AxisConfig {
        method: AxisMethod::Opposing,
        range_px: Some(8.0),
    };
    let err = estimate_axis(&scene, &config, &Silent)
        .unwrap_err()
        .to_string();
    assert!(err.contains("full turn"), "{err}");
}

#[test]
fn a_minimum_at_the_edge_of_the_search_is_refused() {
    let scene = scan(Beam::Parallel, 1, 90, 2.0 * PI, 6.0);
    let config = AxisConfig {
        method: AxisMethod::Opposing,
        range_px: Some(3.0),
    };
    let err = estimate_axis(&scene, &config, &Silent)
        .unwrap_err()
        .to_string();
    assert!(err.contains("range_px"), "{err}");
}

#[test]
fn the_progress_total_matches_the_candidates_scored() {
    let scene = scan(Beam::Parallel, 1, 90, 2.0 * PI, 1.0);
    let config = AxisConfig {
        method: AxisMethod::Opposing,
        range_px: Some(5.0),
    };
    let counter = Counter::default();
    estimate_axis(&scene, &config, &counter).unwrap();
    let (total, last) = *counter.0.lock().unwrap();
    assert!(total > 0);
    assert_eq!(
        total, last,
        "the phase's total is the number of candidates scored"
    );
}
