/// Everything that can go wrong in the simulator crate.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("MuJoCo could not compile the world with object {variant}: {message}")]
    Compile { variant: String, message: String },
    #[error("the world model lacks `{name}` ({what})")]
    MissingName { what: &'static str, name: String },
    #[error(
        "no launch reaches the palm within the configured ranges after {attempts} attempts; hint: widen `speed_mps` or bring `launch_distance_m` closer"
    )]
    NoFeasibleLaunch { attempts: u32 },
    #[error("invalid world spec: {0}")]
    Spec(String),
    #[error("invalid params: {0}")]
    Params(String),
}

pub type Result<T, E = SimError> = std::result::Result<T, E>;
