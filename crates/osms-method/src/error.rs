/// Everything that can go wrong in the method crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A param outside its valid range; the message names it and what is valid.
    #[error("{0}")]
    Params(String),

    // The manifold (paper 4.1).
    #[error("the manifold needs at least 2 windows with all H_OS steps, got {0}")]
    TooFewWindows(usize),
    #[error("window {index}: ζ has {got} values, expected {expected} (H_OS × arm channels)")]
    WindowZetaLength {
        index: usize,
        got: usize,
        expected: usize,
    },
    #[error("window {index}: ω̄ has {got} values, expected {expected} (as the first window)")]
    WindowOmegaLength {
        index: usize,
        got: usize,
        expected: usize,
    },

    // Candidate search.
    #[error("the Sobol table has no {0}-dimensional points")]
    SobolDimension(usize),
    #[error("the Sobol directions are linearly dependent under the metric")]
    DependentDirections,
    #[error("ζ_org has {got} values, the manifold {expected}")]
    SnippetLength { got: usize, expected: usize },

    // The action-error model (paper 4.3).
    #[error("the model needs at least one action channel")]
    NoChannels,
    #[error("no sequences to fit")]
    NoSequences,
    #[error("invalid fit parameters: {0}")]
    InvalidFitParams(String),
    #[error(
        "sequence {sequence}: student has {student} values and teacher {teacher}, \
         but {steps} phases × {channels} channels need {expected}"
    )]
    LengthMismatch {
        sequence: usize,
        student: usize,
        teacher: usize,
        steps: usize,
        channels: usize,
        expected: usize,
    },
    #[error("sequence {sequence}, step {step}: phase {phase} is out of range (phases are 0..=4)")]
    PhaseOutOfRange {
        sequence: usize,
        step: usize,
        phase: u8,
    },
    #[error("sequence {sequence}, step {step}: an action is not finite")]
    NonFinite { sequence: usize, step: usize },
    #[error("all phases pooled: {samples} {what}, at least {needed} needed")]
    TooFewPooledSamples {
        samples: usize,
        needed: usize,
        what: &'static str,
    },
    #[error("malformed action-error model: {0}")]
    MalformedModel(String),

    // Rollouts that must repeat what an input recorded.
    #[error(
        "D_R item {item}: the teacher's replay up to {until} is not the recorded rollout\nhint: `teacher` must be the teacher that collected `data`"
    )]
    ReplayDiverged { item: u32, until: String },
    #[error(
        "{what} does not repeat its validation\nhint: the validation was built from other inputs; rebuild it"
    )]
    NotRepeated { what: String },
    #[error(
        "extension item {index}: the teacher failed {attempts} attempts in a row\nhint: raise params.max_attempts"
    )]
    NoTeacherSuccess { index: usize, attempts: u32 },
    #[error("extension item {index}: {source}")]
    Extension {
        index: usize,
        #[source]
        source: Box<Error>,
    },
    /// Validation or D_* inputs that belong to other rollouts or candidate sets.
    #[error("{0}")]
    MismatchedInputs(String),

    #[error(transparent)]
    Network(#[from] osms_nn::Error),
    #[error(transparent)]
    Policy(#[from] osms_policy::Error),
    #[error(transparent)]
    Sim(#[from] osms_sim::SimError),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl From<osms_core::check::Invalid> for Error {
    fn from(e: osms_core::check::Invalid) -> Self {
        Error::Params(format!("params.{}: {}", e.path.join("."), e.message))
    }
}
