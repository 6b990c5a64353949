//! `[remotes.NAME]` tables, of pipeline.toml and of the user config.

use serde::Deserialize;

/// `[remotes.NAME]`: a remote artifact cache. Credentials never go here: they come from the
/// environment (the standard `AWS_*` variables).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RemoteSpec {
    /// `s3://BUCKET/PREFIX`, `http(s)://HOST/PATH` or `file:///PATH`.
    pub url: String,
}
