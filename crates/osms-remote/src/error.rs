use osms_store::Hash;

/// Everything that can go wrong talking to a remote. Each names the remote and its URL (never a
/// credential: those come from the environment and stay there) and says what to check.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(
        "remote `{remote}`: `{url}` is not a remote URL: {reason}\nhint: use s3://BUCKET/PREFIX, http(s)://HOST/PATH or file:///ABSOLUTE/PATH"
    )]
    Url {
        remote: String,
        url: String,
        reason: String,
    },
    #[error(
        "remote `{remote}` ({url}) is unreachable: {detail}\nhint: check that the server runs and that the URL (or AWS_ENDPOINT_URL) names it; plain http needs AWS_ALLOW_HTTP=true"
    )]
    Unreachable {
        remote: String,
        url: String,
        detail: String,
    },
    #[error(
        "remote `{remote}` ({url}) refused the credentials: {detail}\nhint: check AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (and AWS_SESSION_TOKEN, AWS_REGION) in the environment; osms reads credentials only from there"
    )]
    Denied {
        remote: String,
        url: String,
        detail: String,
    },
    #[error(
        "remote `{remote}` ({url}) has no bucket `{bucket}`\nhint: create it on the server (osms never creates buckets), or fix the URL"
    )]
    NoBucket {
        remote: String,
        url: String,
        bucket: String,
    },
    #[error(
        "remote `{remote}` ({url}) holds a damaged object {object}: its bytes hash to {actual}; it was not stored\nhint: push again from a store that holds it intact (a push replaces an object whose size is wrong; one of the right size must first be removed on the server)"
    )]
    Corrupt {
        remote: String,
        url: String,
        object: Hash,
        actual: Hash,
    },
    #[error(
        "remote `{remote}` ({url}) holds an unreadable record for key {key}: {reason}\nhint: push the stage again from a store that built it (`osms push` replaces the record)"
    )]
    BadRecord {
        remote: String,
        url: String,
        key: Hash,
        reason: String,
    },
    #[error(
        "remote `{remote}` ({url}) has a record for key {key} but not its object {object}\nhint: push again from the store that built it"
    )]
    MissingObject {
        remote: String,
        url: String,
        key: Hash,
        object: Hash,
    },
    #[error("remote `{remote}` ({url}): {what} failed: {detail}")]
    Transfer {
        remote: String,
        url: String,
        what: String,
        detail: String,
    },
    #[error(transparent)]
    Store(#[from] osms_store::Error),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
