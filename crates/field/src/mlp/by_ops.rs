//! NAF's MLP composed from a backend's own tensor ops: the backends without a fused kernel
//! (wgpu).

use super::MlpLayout;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, TensorMetadata, get_or_init_device_settings};
use burn::tensor::{Shape, Slice};

type F<B> = FloatTensor<B>;

fn range<B: Backend>(t: F<B>, start: usize, end: usize) -> F<B> {
    B::float_slice(t, &[Slice::from(start..end)])
}

fn columns<B: Backend>(t: F<B>, rows: usize, start: usize, end: usize) -> F<B> {
    B::float_slice(t, &[Slice::from(0..rows), Slice::from(start..end)])
}

/// Layer `l`'s weight `[d_in, d_out]` and bias `[1, d_out]`.
fn layer<B: Backend>(layout: &MlpLayout, params: &F<B>, l: usize) -> (F<B>, F<B>) {
    let (d_in, d_out) = (layout.d_in(l), layout.d_out(l));
    let (wo, bo) = layout.offsets(l);
    let w = B::float_reshape(
        range::<B>(params.clone(), wo, bo),
        Shape::new([d_in, d_out]),
    );
    let b = B::float_reshape(
        range::<B>(params.clone(), bo, bo + d_out),
        Shape::new([1, d_out]),
    );
    (w, b)
}

fn leaky<B: Backend>(layout: &MlpLayout, z: F<B>) -> F<B> {
    B::leaky_relu(z, layout.slope.into())
}

/// Each layer's input and pre-activation, and the output `[N, 1]`.
fn pass<B: Backend>(layout: &MlpLayout, enc: &F<B>, params: &F<B>) -> Vec<(F<B>, F<B>)> {
    let mut saved: Vec<(F<B>, F<B>)> = Vec::with_capacity(layout.layers);
    let mut x = enc.clone();
    for l in 0..layout.layers {
        if l > 0 {
            x = leaky::<B>(layout, saved[l - 1].1.clone());
            if layout.encoding_rows(l).is_some() {
                x = B::float_cat(vec![x, enc.clone()], 1);
            }
        }
        let (w, b) = layer::<B>(layout, params, l);
        let z = B::float_add(B::float_matmul(x.clone(), w), b);
        saved.push((x.clone(), z));
    }
    saved
}

/// The outputs `[N, 1]`.
pub fn forward<B: Backend>(layout: &MlpLayout, enc: F<B>, params: F<B>) -> F<B> {
    let mut saved = pass::<B>(layout, &enc, &params);
    saved.pop().expect("at least two layers").1
}

/// The gradients with respect to `enc` `[N, input]` and the packed parameters.
pub fn backward<B: Backend>(
    layout: &MlpLayout,
    enc: F<B>,
    params: F<B>,
    grad: F<B>,
) -> (F<B>, F<B>) {
    let n = enc.shape()[0];
    let saved = pass::<B>(layout, &enc, &params);
    let mut dz = grad;
    let mut d_enc: Option<F<B>> = None;
    let mut pieces: Vec<F<B>> = Vec::with_capacity(2 * layout.layers);
    for l in (0..layout.layers).rev() {
        let (x, _) = &saved[l];
        let (w, _) = layer::<B>(layout, &params, l);
        let dw = B::float_matmul(B::float_transpose(x.clone()), dz.clone());
        let db = B::float_sum_dim(dz.clone(), 0);
        let size = layout.d_in(l) * layout.d_out(l);
        pieces.push(B::float_reshape(db, Shape::new([layout.d_out(l)])));
        pieces.push(B::float_reshape(dw, Shape::new([size])));
        let dx = B::float_matmul(dz, B::float_transpose(w));
        if let Some(from) = layout.encoding_rows(l) {
            let part = columns::<B>(dx.clone(), n, from, from + layout.input);
            d_enc = Some(match d_enc {
                Some(d) => B::float_add(d, part),
                None => part,
            });
        }
        if l == 0 {
            break;
        }
        let dx = columns::<B>(dx, n, 0, layout.width);
        let z = saved[l - 1].1.clone();
        let scaled = B::float_mul_scalar(dx.clone(), layout.slope.into());
        let bool_dtype = get_or_init_device_settings::<B>(&z.device()).bool_dtype;
        let below = B::float_lower_elem(z, 0f32.into(), bool_dtype);
        dz = B::float_mask_where(dx, below, scaled);
    }
    pieces.reverse();
    let d_enc = d_enc.expect("layer 0 reads the encoding");
    (d_enc, B::float_cat(pieces, 0))
}
