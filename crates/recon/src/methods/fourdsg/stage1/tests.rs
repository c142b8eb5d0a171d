//! Stage 1's joint fit: targets, gains and an interleaved scene end to end.

use super::*;
use crate::device::upload;
use crate::device::{cpu_device, host_values};
use crate::gaussians::train::ChannelMix;
use crate::methods::fourdsg::FourDsgMethod;
use crate::pipeline::gaussian_tests::tiny;
use crate::pipeline::tests::{run_into, scene};
use crate::record::RunDir;
use crate::{Error, MethodConfig};
use prism_domain::physics::ChannelSpec;
use prism_render::project;

/// The test scene interleaved: channel c measured at the training views v ≡ c (mod 2), zero
/// elsewhere.
fn interleaved() -> Scene {
    let mut sc = scene();
    for &v in &sc.split.train.clone() {
        for c in 0..2 {
            let on = v % 2 == c;
            sc.availability[[v, c]] = on;
            if !on {
                sc.projections.slice_mut(s![c, v, .., ..]).fill(0.0);
            }
        }
    }
    sc
}

#[test]
fn gains_count_only_the_views_a_channel_was_measured_at() {
    let mut sc = scene();
    // Channel 0 reads 2 everywhere, channel 1 reads 1 where measured (missing, and 0, at every
    // third training view): the ratios are 2/1.5 and 1/1.5, whatever the missing views hold.
    sc.projections.slice_mut(s![0, .., .., ..]).fill(2.0);
    sc.projections.slice_mut(s![1, .., .., ..]).fill(1.0);
    for v in (0..24).step_by(3) {
        sc.projections.slice_mut(s![1, v, .., ..]).fill(0.0);
    }
    let r = sc.channel_ratios(sc.train_views());
    assert!((r[0] - 4.0 / 3.0).abs() < 1e-12, "{r:?}");
    assert!((r[1] - 2.0 / 3.0).abs() < 1e-12, "{r:?}");
}

#[test]
fn auto_takes_the_mean_when_every_view_has_every_channel_and_joint_otherwise() {
    let mut full = scene();
    full.availability.fill(true);
    assert_eq!(
        resolve(StructuralSource::Auto, &full),
        StructuralSource::Mean
    );
    assert_eq!(
        resolve(StructuralSource::Auto, &scene()),
        StructuralSource::Joint
    );
    assert_eq!(
        resolve(StructuralSource::Mean, &scene()),
        StructuralSource::Mean
    );
}

/// The joint loss at a view is the per-channel losses of the channels measured there: the basis
/// head's image, column-selected, against the joint target equals, summed over pixels, each
/// channel's own comparison (a one-column model holding that channel's density, rendered,
/// against its measured view). Mono channels are linear in the basis, so the two agree to
/// rounding.
#[test]
fn the_joint_loss_is_the_sum_of_the_per_channel_losses_where_they_exist() {
    let sc = interleaved();
    let dev = cpu_device();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.spectral.structural = StructuralSource::Joint;
    let t = targets(&cfg, &sc).unwrap();
    assert_eq!(t.views, (0..24).collect::<Vec<_>>());
    assert_eq!(t.total, 2);
    let stack = t.start_stack(&sc.geometry);
    let (mut model, world) =
        initial_model(&cfg.geometry, &sc.geometry, stack.view(), &t.views, &dev).unwrap();
    let sup = Supervision::new(
        &sc.geometry,
        &world,
        &t.views,
        t.images.clone(),
        t.columns.clone(),
        t.total,
        &dev,
    );
    let specs = [40.0, 70.0].map(|kev| ChannelSpec::Mono { kev });
    let head = BasisHead::new(&cfg.spectral.joint.basis(), "joint", &specs, &world, &dev).unwrap();
    model.set_densities(upload(
        head.initial_raw(&model.to_host().densities),
        2,
        &dev,
    ));
    let channel_raw = head.channel_raw(&model);
    let options = cfg.geometry.projection.options();
    let f = world.projection_factor() as f32;
    let render = |m: &crate::gaussians::GaussianModel, camera| {
        project(&m.activate(None).gaussians, &[camera], None, &options).unwrap()
    };
    for (i, view) in sup.views.iter().enumerate().step_by(5) {
        let v = t.views[i];
        assert_eq!(sc.available_channels(v), vec![v % 2]);
        let mut img = ChannelMap::Mix(&head).project(render(&model, view.camera));
        if let Some(c) = &view.columns {
            img = img.select(1, c.index.clone());
        }
        let joint: f64 = host_values(&(img - view.target.clone()).abs().reshape([-1]))
            .iter()
            .map(|&x| x as f64)
            .sum();
        let mut per_channel = 0.0f64;
        for c in sc.available_channels(v) {
            let mut one = model.clone();
            let k = channel_raw.dims()[0];
            one.set_densities(channel_raw.clone().slice([0..k, c..c + 1]));
            let rendered = host_values(&render(&one, view.camera).reshape([-1]));
            let measured = sc.channel_projections(c).index_axis(Axis(0), v).to_owned();
            per_channel += rendered
                .iter()
                .zip(measured.iter())
                .map(|(&r, &p)| (r as f64 - (p * f) as f64).abs())
                .sum::<f64>();
        }
        assert!(
            (joint - per_channel).abs() <= 1e-4 * per_channel.max(1.0),
            "view {v}: joint {joint} vs per-channel {per_channel}"
        );
    }
}

#[test]
fn an_interleaved_scene_trains_both_stages_with_no_structural_projection() {
    let sc = interleaved();
    let mut cfg = tiny(FourDsgMethod::Full);
    cfg.spectral.stage2.iterations = 20;
    let dir = tempfile::tempdir().unwrap();
    let config = MethodConfig::from(cfg.clone());
    let outcome = run_into(&config, &sc, dir.path(), false).unwrap();
    let metrics = outcome.metrics.unwrap();
    for ch in &metrics.channels {
        assert!(
            ch.scores.psnr.is_finite() && ch.scores.psnr > 15.0,
            "{ch:?}"
        );
    }
    let log = std::fs::read_to_string(dir.path().join(RunDir::LOG)).unwrap();
    assert!(
        log.contains(r#""stage":"geometry","channel":"joint""#),
        "{log}"
    );
    assert!(log.contains(r#""stage":"gscnet""#), "{log}");

    // The mean structural projection needs a view with every channel: refused, naming the way out.
    let mut mean = cfg;
    mean.spectral.structural = StructuralSource::Mean;
    let config = MethodConfig::from(mean);
    let e = run_into(&config, &sc, tempfile::tempdir().unwrap().path(), false).unwrap_err();
    assert!(matches!(e, Error::Domain(_)), "{e}");
    assert!(e.to_string().contains("structural: joint"), "{e}");
}
