/// What the network core refuses.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("an MLP needs at least an input and an output size, got {sizes:?}")]
    TooFewSizes { sizes: Vec<usize> },
    #[error(
        "layer {layer} of an MLP with sizes {sizes:?} has no units\nhint: every width in `hidden` must be at least 1"
    )]
    EmptyLayer { layer: usize, sizes: Vec<usize> },
    #[error(
        "a U-Net with level widths {widths:?} over {steps} steps and kernel {kernel} cannot be built\nhint: at least one level, every width and the step count at least 1, an odd kernel, and steps that halve once per level after the first"
    )]
    UNetShape {
        widths: Vec<usize>,
        steps: usize,
        kernel: usize,
    },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
