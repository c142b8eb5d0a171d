//! GSC-Net: a Gaussian-wise spectral density curve network.
//!
//! Maps each Gaussian's common raw density and the ordered spectral grid to a raw density curve
//! Δu [K, M] (paper Sec. III-D). This crate is a leaf: it knows nothing about scenes or rendering.
