/// What the network core refuses.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("an MLP needs at least an input and an output size, got {sizes:?}")]
    TooFewSizes { sizes: Vec<usize> },
    #[error(
        "layer {layer} of an MLP with sizes {sizes:?} has no units\nhint: every width in `hidden` must be at least 1"
    )]
    EmptyLayer { layer: usize, sizes: Vec<usize> },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
