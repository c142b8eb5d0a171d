use super::*;
use crate::geometry::Beam;
use crate::testing::{analytic_projections, geometry, phantom, random, rel_l2, voxelise};
use ndarray::Axis;

#[test]
fn adjoint_identity_cone_and_parallel_with_offsets() {
    // ⟨A x, y⟩ = ⟨x, Aᵀ y⟩ exactly in real arithmetic; f32 accumulation of O(10⁶) terms leaves
    // ≲ 1e-6 relative, well inside the 1e-5 acceptance bound.
    for beam in [Beam::Cone, Beam::Parallel] {
        let mut g = geometry(beam, 24, 32, 7, true);
        g.volume.dy = 0.8; // anisotropic voxels too
        g.angles_rad = vec![0.1, 0.9, 1.7, 2.4, 3.3, 4.4, 5.9];
        let a = Joseph::new(&g).unwrap();
        let x = random(g.volume.shape_zyx(), 1);
        let y = random(a.projection_shape(a.views()), 2);
        let ax = a.forward(x.view()).unwrap();
        let aty = a.adjoint(y.view()).unwrap();
        let (lhs, rhs) = (dot(ax.view(), y.view()), dot(x.view(), aty.view()));
        let rel = (lhs - rhs).abs() / lhs.abs();
        assert!(rel <= 1e-5, "{beam:?}: {lhs} vs {rhs} ({rel:e})");
        // Subsets of views are the same operator restricted.
        let sub = [5usize, 2];
        let axs = a.forward_views(x.view(), &sub).unwrap();
        for (k, &v) in sub.iter().enumerate() {
            assert_eq!(axs.index_axis(Axis(0), k), ax.index_axis(Axis(0), v));
        }
    }
}

#[test]
fn empty_space_skipping_is_exact() {
    // The forward projector clips rays to the non-zero voxels' bounding box; the adjoint always
    // walks the whole grid. The dot-product test on a volume that is zero outside a small
    // off-centre box (touching one face of the grid) checks that nothing is lost, and an
    // all-zero volume projects to exactly zero.
    let g = geometry(Beam::Cone, 24, 32, 7, true);
    let a = Joseph::new(&g).unwrap();
    let mut x = random(g.volume.shape_zyx(), 3);
    for ((z, y, xx), v) in x.indexed_iter_mut() {
        if !(3..9).contains(&z) || !(0..6).contains(&y) || !(14..20).contains(&xx) {
            *v = 0.0;
        }
    }
    let y = random(a.projection_shape(a.views()), 4);
    let lhs = dot(a.forward(x.view()).unwrap().view(), y.view());
    let rhs = dot(x.view(), a.adjoint(y.view()).unwrap().view());
    assert!((lhs - rhs).abs() / lhs.abs() <= 1e-5, "{lhs} vs {rhs}");
    let zero = Array3::<f32>::zeros(g.volume.shape_zyx());
    assert!(a.forward(zero.view()).unwrap().iter().all(|&v| v == 0.0));
}

#[test]
fn central_ray_through_a_uniform_cube_is_its_width() {
    // With an odd detector and no offsets the middle pixel's ray is the central ray: at θ = 0 it
    // runs along −x through the middle of the cube, 16 voxels of 1 mm and value 1 → 16 mm.
    for beam in [Beam::Cone, Beam::Parallel] {
        let mut g = geometry(beam, 16, 33, 1, false);
        g.angles_rad = vec![0.0];
        let a = Joseph::new(&g).unwrap();
        let ones = Array3::<f32>::ones(g.volume.shape_zyx());
        let p = a.forward(ones.view()).unwrap();
        assert!(
            (p[[0, 16, 16]] - 16.0).abs() < 1e-4,
            "{beam:?} {}",
            p[[0, 16, 16]]
        );
    }
}

#[test]
fn forward_projection_converges_to_analytic_projections() {
    // Voxelising + trilinear sampling is first-order accurate at the ellipsoid boundaries, so the
    // relative error must shrink roughly in proportion to the voxel size (measured 4.9 % at 24³,
    // 2.4 % at 48³: halving the voxel halves the error).
    let mut errs = Vec::new();
    for n in [24usize, 48] {
        let mut g = geometry(Beam::Cone, n, 48, 6, true);
        g.volume.dx = 32.0 / n as f64;
        g.volume.dy = g.volume.dx;
        g.volume.dz = g.volume.dx;
        g.detector.pitch_u = 48.0 / 48.0;
        g.detector.pitch_v = 0.9;
        g.dso = 200.0;
        g.dsd = 300.0;
        let objs = phantom(16.0);
        let a = Joseph::new(&g).unwrap();
        let vol = voxelise(&g.volume, &objs, 4);
        let fp = a.forward(vol.view()).unwrap();
        let truth = analytic_projections(&g, &objs);
        errs.push(rel_l2(&fp, &truth));
    }
    eprintln!("fp vs analytic: {errs:?}");
    assert!(errs[1] < 0.6 * errs[0] && errs[1] < 0.03, "{errs:?}");
}

#[test]
fn bad_inputs_are_errors() {
    let g = geometry(Beam::Cone, 8, 8, 3, false);
    let a = Joseph::new(&g).unwrap();
    let wrong = Array3::<f32>::zeros((8, 8, 9));
    assert!(
        a.forward(wrong.view())
            .unwrap_err()
            .to_string()
            .contains("volume")
    );
    let vol = Array3::<f32>::zeros((8, 8, 8));
    assert!(
        a.forward_views(vol.view(), &[])
            .unwrap_err()
            .to_string()
            .contains("empty")
    );
    assert!(a.forward_views(vol.view(), &[3]).is_err());
    let p = Array3::<f32>::zeros((2, 8, 8));
    assert!(
        a.adjoint(p.view())
            .unwrap_err()
            .to_string()
            .contains("projections")
    );
    let mut bad = g.clone();
    bad.angles_rad.clear();
    assert!(
        Joseph::new(&bad)
            .unwrap_err()
            .to_string()
            .contains("angles_rad")
    );
}

/// The projector with the sheets and the vector sampler switched as asked.
fn variant(g: &Geometry, sheets: bool, simd: bool) -> Joseph {
    let mut a = Joseph::new(g).unwrap();
    a.sheets = sheets;
    a.simd = simd && a.simd;
    a
}

#[test]
fn column_sheets_match_the_per_ray_walk() {
    // The sheet factorisation (horizontal interpolation once per column, then one z
    // interpolation per ray and plane) is the same bilinear sum as the per-ray walk; only the
    // float evaluation order differs (f32, ≲ 1e-6 relative), for the scalar and AVX2 samplers,
    // one view (volume in [z][y][x]) and many (z-fastest copy), and for the adjoint.
    for beam in [Beam::Cone, Beam::Parallel] {
        let mut g = geometry(beam, 20, 28, 6, true);
        g.volume.dy = 0.8;
        g.volume.nz = 17;
        let x = random(g.volume.shape_zyx(), 5);
        let y = random([6, 28, 28], 6);
        let walk = variant(&g, false, false);
        let fw = walk.forward(x.view()).unwrap();
        let bw = walk.adjoint(y.view()).unwrap();
        for simd in [false, true] {
            let a = variant(&g, true, simd);
            let e = rel_l2(&a.forward(x.view()).unwrap(), &fw);
            assert!(e < 1e-5, "{beam:?} simd={simd}: forward {e:e}");
            let one = a.forward_views(x.view(), &[4]).unwrap();
            let e1 = rel_l2(&one, &fw.slice(ndarray::s![4..5, .., ..]).to_owned());
            assert!(e1 < 1e-5, "{beam:?} simd={simd}: one view {e1:e}");
            let e = rel_l2(&a.adjoint(y.view()).unwrap(), &bw);
            assert!(e < 1e-5, "{beam:?} simd={simd}: adjoint {e:e}");
        }
    }
}

#[test]
fn a_lone_row_reads_the_volume_as_its_sheet_would_bit_for_bit() {
    // A one-row detector (a fan beam over one slice, and a tilted row over a slab, whose ray
    // crosses z planes and meets the sheet's clamped end rows) skips the sheet and computes its
    // entries where the ray reads them. Same sums in the same order: identical bits, forward
    // (many views: z-fastest copy; one view: [z][y][x]) and adjoint, scalar and AVX2 samplers.
    for nz in [1, 5] {
        let mut g = geometry(Beam::Cone, 24, 30, 7, true);
        g.detector.rows = 1;
        g.detector.offset_v = if nz == 1 { 0.0 } else { 2.5 };
        g.volume.nz = nz;
        g.volume.dy = 0.8;
        let x = random(g.volume.shape_zyx(), 7);
        let y = random([7, 1, 30], 8);
        for simd in [false, true] {
            let lone = variant(&g, true, simd);
            let mut sheet = variant(&g, true, simd);
            sheet.lone = false;
            let (fl, fs) = (
                lone.forward(x.view()).unwrap(),
                sheet.forward(x.view()).unwrap(),
            );
            assert!(
                fs.iter().any(|&v| v != 0.0),
                "nz={nz}: the rays miss the volume"
            );
            let bits = |a: &Array3<f32>| a.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&fl), bits(&fs), "nz={nz} simd={simd}: forward");
            let (ol, os) = (
                lone.forward_views(x.view(), &[3]).unwrap(),
                sheet.forward_views(x.view(), &[3]).unwrap(),
            );
            assert_eq!(bits(&ol), bits(&os), "nz={nz} simd={simd}: one view");
            let (bl, bs) = (
                lone.adjoint(y.view()).unwrap(),
                sheet.adjoint(y.view()).unwrap(),
            );
            assert_eq!(bits(&bl), bits(&bs), "nz={nz} simd={simd}: adjoint");
            let (vl, vs) = (
                lone.adjoint_views(y.slice(ndarray::s![2..3, .., ..]), &[2])
                    .unwrap(),
                sheet
                    .adjoint_views(y.slice(ndarray::s![2..3, .., ..]), &[2])
                    .unwrap(),
            );
            assert_eq!(
                bits(&vl),
                bits(&vs),
                "nz={nz} simd={simd}: one view's adjoint"
            );
        }
    }
}

#[test]
fn steep_cone_rays_fall_back_to_the_general_walk() {
    // A 16 mm grid seen from 20 mm with a 96 mm tall detector at 30 mm: the outer rows are steeper
    // than 45° (z-dominant) and take the general walk, the rest use sheets. Both together must
    // still be one operator with an exact adjoint, and agree with the analytic line integrals.
    let mut g = geometry(Beam::Cone, 16, 32, 5, true);
    g.dso = 20.0;
    g.dsd = 30.0;
    g.detector.pitch_v = 3.0;
    let cam = g.camera(0);
    let top = cam.pixel_ray(16.0, 0.0);
    assert!(
        top.direction[2].abs() > 0.8,
        "rows must include z-dominant rays"
    );
    for simd in [false, true] {
        let a = variant(&g, true, simd);
        let x = random(g.volume.shape_zyx(), 7);
        let y = random(a.projection_shape(a.views()), 8);
        let lhs = dot(a.forward(x.view()).unwrap().view(), y.view());
        let rhs = dot(x.view(), a.adjoint(y.view()).unwrap().view());
        assert!((lhs - rhs).abs() / lhs.abs() <= 1e-5, "{lhs} vs {rhs}");
    }
    let objs = phantom(7.0);
    let vol = voxelise(&g.volume, &objs, 4);
    let truth = analytic_projections(&g, &objs);
    let fp = Joseph::new(&g).unwrap().forward(vol.view()).unwrap();
    let reference = variant(&g, false, false).forward(vol.view()).unwrap();
    assert!(rel_l2(&fp, &reference) < 1e-5);
    // First-order voxelisation error: the body is ~11 voxels across here, about half the 24³
    // case of the convergence test (4.9 %), so ≈ 10 %; the bound allows for the coarser grid.
    let e = rel_l2(&fp, &truth);
    eprintln!("steep cone fp vs analytic: {e}");
    assert!(e < 0.12, "fp vs analytic {e}");
}

#[test]
fn per_view_vectors_project_as_analytic_line_integrals_and_stay_adjoint() {
    // A disturbed scan (source wobble, detector spin, tilt and shift per view: its columns no
    // longer run along z, so every ray takes the general walk). Against the ellipsoids' exact
    // chords the error is the voxelisation's, as for a circular scan (< 3 % at 48³); the
    // transpose is exact to f32 accumulation (1e-5, as above).
    for beam in [Beam::Cone, Beam::Parallel] {
        let mut g = geometry(beam, 48, 48, 6, true);
        g.volume.dx = 32.0 / 48.0;
        g.volume.dy = g.volume.dx;
        g.volume.dz = g.volume.dx;
        g.detector.pitch_u = 1.0;
        g.detector.pitch_v = 0.9;
        g.dso = 200.0;
        g.dsd = 300.0;
        let g = crate::testing::wobbled(&g);
        let a = Joseph::new(&g).unwrap();
        let objs = phantom(16.0);
        let vol = voxelise(&g.volume, &objs, 4);
        let fp = a.forward(vol.view()).unwrap();
        let truth = analytic_projections(&g, &objs);
        let err = rel_l2(&fp, &truth);
        eprintln!("{beam:?}: fp vs analytic on disturbed vectors {err:.4}");
        assert!(err < 0.03, "{beam:?}: {err}");
        let x = random(g.volume.shape_zyx(), 5);
        let y = random(a.projection_shape(a.views()), 6);
        let lhs = dot(a.forward(x.view()).unwrap().view(), y.view());
        let rhs = dot(x.view(), a.adjoint(y.view()).unwrap().view());
        let rel = (lhs - rhs).abs() / lhs.abs();
        assert!(rel <= 1e-5, "{beam:?}: {lhs} vs {rhs} ({rel:e})");
    }
}
