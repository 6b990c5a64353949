/// What the report cannot render.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("figure `{figure}`: {message}")]
    Draw { figure: String, message: String },
    #[error("figure `{figure}`: PNG encoding: {source}")]
    Png {
        figure: String,
        #[source]
        source: png::EncodingError,
    },
    #[error("claims as JSON: {0}")]
    Json(#[from] serde_json::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
