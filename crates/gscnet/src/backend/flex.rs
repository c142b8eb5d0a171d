//! Flex adapter: borrow contiguous f32 buffers, build outputs from owned `Vec`s (zero copy).

use burn::backend::{Flex, TensorMetadata, flex::FlexTensor, tensor::FloatTensor};
use burn::tensor::TensorData;

fn read<R>(t: &FlexTensor, f: impl FnOnce(&[f32]) -> R) -> R {
    match t.as_slice::<f32>() {
        Some(s) => f(s),
        None => {
            let c = t.to_contiguous();
            // The modules build f32 tensors, so a non-f32 primitive here is a caller bug.
            f(c.as_slice::<f32>()
                .expect("prism-gscnet ops take f32 tensors"))
        }
    }
}

fn write(v: Vec<f32>, shape: Vec<usize>) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(v, shape))
}

fn dims(t: &FlexTensor) -> Vec<usize> {
    t.shape().to_vec()
}

super::impl_cpu_spectral_ops!(Flex, read, write, dims);
