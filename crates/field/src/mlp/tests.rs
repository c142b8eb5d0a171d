//! The fused MLP against an f64 reference of its definition and central finite differences.

use super::*;
use crate::tests::random;

fn layout() -> MlpLayout {
    MlpLayout {
        input: 6,
        width: 5,
        layers: 4,
        skip: 2,
        slope: 0.01,
    }
}

/// A layout whose layers take every tile shape: 41 = 32 + 8 + 1 outputs (2-, 4- and 8-row
/// tiles), with 11, 41 and 52 inputs (every tile height leaves a remainder).
fn tiled() -> MlpLayout {
    MlpLayout {
        input: 11,
        width: 41,
        ..layout()
    }
}

/// The test layouts with a parameter range that keeps activations of order one, and the
/// stride of the parameters the finite-difference test perturbs.
fn cases() -> [(MlpLayout, f32, usize); 2] {
    [(layout(), 0.6, 3), (tiled(), 0.2, 23)]
}

/// The MLP of the module docs, one point at a time, in f64. Each LeakyReLU's branch
/// (below 0 or not) is read from `branches` when given, else chosen and recorded there: a
/// finite difference with the branches of the unperturbed point differentiates the piece
/// of the (piecewise linear) network the point lies on, with no kink inside the step.
fn reference(
    layout: &MlpLayout,
    enc: &[f32],
    params: &[f32],
    branches: &mut Vec<bool>,
    fixed: bool,
) -> Vec<f64> {
    let mut next = 0;
    enc.chunks_exact(layout.input)
        .map(|e| {
            let mut x: Vec<f64> = e.iter().map(|&v| v as f64).collect();
            for l in 0..layout.layers {
                if l == layout.skip {
                    x.extend(e.iter().map(|&v| v as f64));
                }
                let (wo, bo) = layout.offsets(l);
                let d_out = layout.d_out(l);
                let mut z: Vec<f64> = (0..d_out).map(|j| params[bo + j] as f64).collect();
                for (k, xk) in x.iter().enumerate() {
                    for (j, zj) in z.iter_mut().enumerate() {
                        *zj += xk * params[wo + k * d_out + j] as f64;
                    }
                }
                if l + 1 == layout.layers {
                    x = z;
                    continue;
                }
                x = z
                    .iter()
                    .map(|&v| {
                        if !fixed {
                            branches.push(v < 0.0);
                        }
                        let below = branches[next];
                        next += 1;
                        if below { v * layout.slope as f64 } else { v }
                    })
                    .collect();
            }
            x[0]
        })
        .collect()
}

#[test]
fn the_packed_layout_holds_every_layer_once() {
    let l = layout();
    // 6→5, 5→5, (5+6)→5, 5→1, each with its bias.
    assert_eq!(l.params(), 7 * 5 + 6 * 5 + 12 * 5 + 6);
    assert_eq!(l.offsets(1), (35, 35 + 25));
}

#[test]
fn the_forward_is_the_mlp_of_the_docs() {
    for (l, range, _) in cases() {
        // More points than a task, so tasks are split and joined; the last task's 37
        // points leave a remainder under every tile height.
        let n = TASK + 37;
        let enc = random(n * l.input, -1.0, 1.0, 11);
        let params = random(l.params(), -range, range, 12);
        let out = cpu_forward(&l, &enc, &params);
        let want = reference(&l, &enc, &params, &mut Vec::new(), false);
        for (i, (a, b)) in out.iter().zip(want).enumerate() {
            let tol = 1e-5 * b.abs().max(1.0);
            assert!((*a as f64 - b).abs() < tol, "{l:?}, point {i}: {a} vs {b}");
        }
    }
}

#[test]
fn the_wide_and_baseline_variants_agree_exactly() {
    // Without FMA the AVX2 build performs the same operations in the same order.
    for (l, range, _) in cases() {
        let n = TASK + 5;
        let enc = random(n * l.input, -1.0, 1.0, 16);
        let params = random(l.params(), -range, range, 17);
        let grad = random(n, -1.0, 1.0, 18);
        let run = |baseline: bool| {
            prism_kernel::simd::force_baseline(baseline);
            let out = (
                cpu_forward(&l, &enc, &params),
                cpu_backward(&l, &enc, &params, &grad),
            );
            prism_kernel::simd::force_baseline(false);
            out
        };
        assert_eq!(run(false), run(true), "{l:?}");
    }
}

#[test]
fn the_backward_matches_finite_differences() {
    for (l, range, stride) in cases() {
        backward_matches_finite_differences(&l, range, stride);
    }
}

fn backward_matches_finite_differences(l: &MlpLayout, range: f32, stride: usize) {
    let n = TASK + 9;
    let enc = random(n * l.input, -1.0, 1.0, 13);
    let params = random(l.params(), -range, range, 14);
    let grad = random(n, -1.0, 1.0, 15);
    let (d_enc, d_params) = cpu_backward(l, &enc, &params, &grad);
    // ⟨grad, f⟩ in f64 on the unperturbed point's branches, differentiated centrally over
    // the step actually taken in f32.
    let mut branches = Vec::new();
    reference(l, &enc, &params, &mut branches, false);
    let loss = |enc: &[f32], params: &[f32]| -> f64 {
        reference(l, enc, params, &mut branches.clone(), true)
            .iter()
            .zip(&grad)
            .map(|(a, &g)| a * g as f64)
            .sum()
    };
    let h = 1e-3f32;
    for k in (0..params.len()).step_by(stride) {
        let (mut up, mut down) = (params.clone(), params.clone());
        up[k] += h;
        down[k] -= h;
        let fd = (loss(&enc, &up) - loss(&enc, &down)) / (up[k] - down[k]) as f64;
        let tol = 1e-4 * fd.abs().max(1.0);
        assert!(
            (fd - d_params[k] as f64).abs() < tol,
            "{l:?}, param {k}: fd {fd} vs {}",
            d_params[k]
        );
    }
    for k in (0..enc.len()).step_by(29) {
        let (mut up, mut down) = (enc.clone(), enc.clone());
        up[k] += h;
        down[k] -= h;
        let fd = (loss(&up, &params) - loss(&down, &params)) / (up[k] - down[k]) as f64;
        assert!(
            (fd - d_enc[k] as f64).abs() < 2e-3,
            "{l:?}, enc {k}: fd {fd} vs {}",
            d_enc[k]
        );
    }
}
