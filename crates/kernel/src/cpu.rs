//! f32 buffers of the CPU backends' tensors, so that one kernel implementation (plain `&[f32]`
//! in, `Vec<f32>` out) is registered for every CPU backend.
//!
//! Reading borrows the tensor's buffer when it is contiguous f32 (no copy); a strided tensor is
//! copied once. Prism's ops take f32 tensors only (their public functions check), so another
//! dtype here is a caller bug and panics.

use burn::backend::Backend;
use burn::backend::tensor::FloatTensor;
use std::borrow::Cow;

/// Element-wise sum of per-task partial results (each `len` long), in task order: a reduction
/// over rayon tasks of a fixed size that gives the same values whatever the thread count.
pub fn sum_partials(partials: Vec<Vec<f32>>, len: usize) -> Vec<f32> {
    let mut total = vec![0.0f32; len];
    for p in partials {
        for (t, v) in total.iter_mut().zip(p) {
            *t += v;
        }
    }
    total
}

/// A CPU backend whose float tensors are host buffers.
pub trait CpuFloat: Backend {
    /// The row-major f32 values of `t`.
    fn values(t: &FloatTensor<Self>) -> Cow<'_, [f32]>;
    /// A tensor of `shape` holding `values` (row-major, taken over without a copy).
    fn tensor(values: Vec<f32>, shape: Vec<usize>) -> FloatTensor<Self>;
    /// The shape of `t`.
    fn dims(t: &FloatTensor<Self>) -> Vec<usize>;

    /// Run `f` on the values of several tensors at once.
    fn with_values<const N: usize, R>(
        ts: [&FloatTensor<Self>; N],
        f: impl FnOnce([&[f32]; N]) -> R,
    ) -> R {
        let values = ts.map(Self::values);
        f(values.each_ref().map(|v| &**v))
    }
}

#[cfg(feature = "flex")]
impl CpuFloat for burn::backend::Flex {
    fn values(t: &FloatTensor<Self>) -> Cow<'_, [f32]> {
        match t.as_slice::<f32>() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(
                t.to_contiguous()
                    .as_slice::<f32>()
                    .expect("Prism's ops take f32 tensors")
                    .to_vec(),
            ),
        }
    }

    fn tensor(values: Vec<f32>, shape: Vec<usize>) -> FloatTensor<Self> {
        burn::backend::flex::FlexTensor::from_data(burn::tensor::TensorData::new(values, shape))
    }

    fn dims(t: &FloatTensor<Self>) -> Vec<usize> {
        burn::backend::TensorMetadata::shape(t).to_vec()
    }
}

// burn-ndarray is deprecated in Burn 0.22 in favour of Flex; it is kept while it exists.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
impl CpuFloat for burn::backend::NdArray {
    fn values(t: &FloatTensor<Self>) -> Cow<'_, [f32]> {
        use burn::backend::ndarray::NdArrayTensor;
        match t {
            NdArrayTensor::F32(storage) => {
                let view = storage.view();
                match view.to_slice() {
                    Some(s) => Cow::Borrowed(s),
                    None => Cow::Owned(view.iter().copied().collect()),
                }
            }
            other => panic!(
                "Prism's ops take f32 tensors, got {:?}",
                burn::backend::TensorMetadata::dtype(other)
            ),
        }
    }

    fn tensor(values: Vec<f32>, shape: Vec<usize>) -> FloatTensor<Self> {
        burn::backend::ndarray::NdArrayTensor::from_data(burn::tensor::TensorData::new(
            values, shape,
        ))
    }

    fn dims(t: &FloatTensor<Self>) -> Vec<usize> {
        burn::backend::TensorMetadata::shape(t).to_vec()
    }
}
