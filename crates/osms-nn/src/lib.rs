//! A deterministic neural-network core: own f32 kernels with a fixed summation order, layers,
//! losses, reverse-mode gradients and Adam, bit-exact across threads and CPUs.
//!
//! Entry points: [`kernels`] (matrix products, reductions), [`Mlp`] (forward, backward),
//! [`UNet1d`] (a temporal convolutional U-Net with FiLM), [`mse`]/[`weighted_mse`], [`Adam`].

mod error;
mod extra;
pub mod kernels;
mod layers;
mod level;
pub mod math;
mod matrix;
mod optim;
mod unet;

pub use error::{Error, Result};
pub use extra::{
    DiagGaussian, GaussianGrad, LayerNorm, LayerNormCache, sinusoidal_embedding,
    sinusoidal_embedding_backward, softmax_cross_entropy,
};
pub use layers::Jet;
pub use layers::{
    Activation, Linear, LinearGrad, Mlp, MlpCache, MlpInference, flatten_grads, mse, weighted_mse,
};
pub use matrix::Matrix;
pub use optim::{Adam, AdamConfig, AdamMoments, Schedule, global_norm};
pub use unet::{Conv1d, ResBlock, ResCache, UNet1d, UNetCache};

/// The numerics version of osms-nn: bump it whenever a kernel, layer, loss or optimiser change
/// may change the bits of a trained network. Kinds that train or run networks put it in their
/// keys. 2: products accumulate with fused multiply-add; reductions use 8 partial sums.
pub const NUMERICS_VERSION: u32 = 2;

impl osms_core::Artifact for Mlp {
    const TYPE_TAG: &'static str = "nn.mlp";
    const SCHEMA_VERSION: u16 = 1;
}
