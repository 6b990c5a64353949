/// What the artifact codec refuses.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("not an osms artifact: {reason}")]
    Foreign { reason: String },
    #[error(
        "artifact format version {found} is newer than this osms understands ({supported}); \
         hint: upgrade osms or rebuild the artifact"
    )]
    NewerFormat { found: u16, supported: u16 },
    #[error("artifact holds a `{found}` but a `{expected}` was expected")]
    WrongType { expected: String, found: String },
    #[error(
        "`{tag}` artifact has schema version {found}, this osms reads version {expected}; \
         hint: rebuild it with `osms make`"
    )]
    SchemaMismatch {
        tag: String,
        found: u16,
        expected: u16,
    },
    #[error("could not encode a `{tag}` artifact: {source}")]
    Encode {
        tag: String,
        #[source]
        source: postcard::Error,
    },
    #[error("could not decode a `{tag}` artifact: {reason}")]
    Decode { tag: String, reason: String },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
