//! The paper's method (section 4.1): the OSW motion manifold (a conditional VAE), projection of
//! an original snippet onto it (Eq. 3), the decoder's pullback metric (Eq. 4), Sobol shooting
//! directions and geodesic shooting (Eq. 5), and the candidate sets η (Eq. 6).

pub mod artifacts;
pub mod candidates;
pub mod construct;
pub mod cvae;
mod error;
pub mod error_model;
pub mod geodesic;
pub mod intervene;
pub mod ios;
mod linalg;
pub mod project;
pub mod select;
pub mod sobol;
pub mod stages;
pub mod validate;

pub use error::{Error, Result};
