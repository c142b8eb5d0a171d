//! NdArray adapter (burn-ndarray is deprecated in 0.22 in favour of Flex; kept while it exists).
#![allow(deprecated)]

use burn::backend::{NdArray, TensorMetadata, ndarray::NdArrayTensor, tensor::FloatTensor};
use burn::tensor::TensorData;

fn read<R>(t: &NdArrayTensor, f: impl FnOnce(&[f32]) -> R) -> R {
    match t {
        NdArrayTensor::F32(storage) => {
            let view = storage.view();
            match view.as_slice() {
                Some(s) => f(s),
                None => f(&view.iter().copied().collect::<Vec<_>>()),
            }
        }
        // The modules build f32 tensors, so a non-f32 primitive here is a caller bug.
        other => panic!("prism-gscnet ops take f32 tensors, got {:?}", other.dtype()),
    }
}

fn write(v: Vec<f32>, shape: Vec<usize>) -> NdArrayTensor {
    NdArrayTensor::from_data(TensorData::new(v, shape))
}

fn dims(t: &NdArrayTensor) -> Vec<usize> {
    t.shape().to_vec()
}

super::impl_cpu_spectral_ops!(NdArray, read, write, dims);
