//! The S3-compatible server of the remote-cache tests and its WebDAV gateway (SeaweedFS on
//! loopback, started by scripts/test through scripts/s3-server, which exports `OSMS_TEST_S3_*`).

/// Where the test server is and how to sign requests to it.
#[derive(Debug, Clone)]
pub struct Server {
    /// `http://127.0.0.1:PORT`: the S3 endpoint.
    pub endpoint: String,
    pub bucket: String,
    pub access_key: String,
    pub secret_key: String,
    /// The server's filer (`http://127.0.0.1:PORT`): a back door that writes bytes under an
    /// object's name without S3, to plant a damaged object.
    pub filer: String,
    /// The server's WebDAV gateway (`http://127.0.0.1:PORT`) on the same files as the filer.
    pub webdav: String,
}

impl Server {
    /// The environment an `osms` process needs to reach the server (the standard `AWS_*`
    /// variables; plain HTTP on loopback).
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            ("AWS_ACCESS_KEY_ID", self.access_key.clone()),
            ("AWS_SECRET_ACCESS_KEY", self.secret_key.clone()),
            ("AWS_ENDPOINT_URL", self.endpoint.clone()),
            ("AWS_ALLOW_HTTP", "true".to_string()),
            ("AWS_REGION", "us-east-1".to_string()),
        ]
    }
}

/// The test server, or `None` after logging a visible skip; under `CI` a missing server fails
/// the test: the test command always starts one there.
pub fn server(check: &str) -> Option<Server> {
    let var = |name: &str| std::env::var(name).ok().filter(|v| !v.is_empty());
    if let (
        Some(endpoint),
        Some(bucket),
        Some(access_key),
        Some(secret_key),
        Some(filer),
        Some(webdav),
    ) = (
        var("OSMS_TEST_S3_ENDPOINT"),
        var("OSMS_TEST_S3_BUCKET"),
        var("OSMS_TEST_S3_ACCESS_KEY"),
        var("OSMS_TEST_S3_SECRET_KEY"),
        var("OSMS_TEST_S3_FILER"),
        var("OSMS_TEST_S3_WEBDAV"),
    ) {
        return Some(Server {
            endpoint,
            bucket,
            access_key,
            secret_key,
            filer,
            webdav,
        });
    }
    let mode = crate::golden::Mode::from_env();
    assert!(
        !mode.ci,
        "{check} needs OSMS_TEST_S3_* under CI (scripts/test starts scripts/s3-server)"
    );
    let line = format!("{check}: OSMS_TEST_S3_ENDPOINT is not set (run scripts/test)");
    eprintln!("skipped: {line}");
    mode.log_skip(&line);
    None
}
