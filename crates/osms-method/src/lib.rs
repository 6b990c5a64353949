//! The paper's method: the OSW motion manifold (conditional VAE), projection, pullback metric and
//! geodesic candidate sets with the ablation generators, the IL-student action-error model and its
//! Table III metrics, candidate validation, D_* and the Naive and Normal baselines, and the IOS
//! profile, with their stage kinds.
//!
//! Rooms: library modules know nothing of the engine: [`cvae`] (the manifold), [`project`] (Eq. 3),
//! [`geodesic`] (Eqs. 4–5), [`sobol`] and [`candidates`] (Eq. 6), [`error_model`] (Eq. 7: model,
//! fit, perturber, Table III metrics) and [`calibrate`] (the models against π̄ in closed loop),
//! [`intervene`], [`validate`] and [`select`] (Eqs. 8–9,
//! Alg. 1), [`construct`] (D_* and the baselines' groups) and [`ios`] (Eq. 1); one small
//! linear-algebra module serves them all. [`artifacts`] holds the stored types and
//! [`stages`] one thin adapter per stage kind.

pub mod artifacts;
pub mod calibrate;
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
