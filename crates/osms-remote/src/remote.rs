//! One remote: where its objects and records live, and the transfers between it and a store.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bytes::Bytes;
use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use object_store::http::HttpBuilder;
use object_store::local::LocalFileSystem;
use object_store::path::Path;
use object_store::{ClientConfigKey, ObjectStore, ObjectStoreExt, RetryConfig};
use osms_store::{Hash, ObjectState, Record, Store};

use crate::error::{Error, Result};

/// Transfers at once: enough to hide a round trip to a remote server, few enough for 2 cores to
/// hash what arrives.
pub const DEFAULT_JOBS: usize = 8;

/// What a transfer shows while it runs (the CLI draws a progress bar with bytes and rate).
pub trait Progress: Sync {
    /// `objects` objects of `bytes` bytes in all are about to move.
    fn begin(&self, _what: &str, _objects: u64, _bytes: u64) {}
    /// `bytes` more have moved.
    fn advance(&self, _bytes: u64) {}
    fn end(&self) {}
}

/// Shows nothing.
pub struct NoProgress;
impl Progress for NoProgress {}

/// What a push did.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct PushReport {
    /// Objects uploaded, and their bytes.
    pub objects_sent: u64,
    pub bytes_sent: u64,
    /// Objects the remote already held (skipped by name and size).
    pub objects_present: u64,
    /// Records written (every record pushed is written: a record is small and replacing it with
    /// the same mapping is harmless).
    pub records: u64,
}

/// What fetching one key did.
#[derive(Debug, Clone)]
pub struct Fetched {
    pub record: Record,
    pub objects_received: u64,
    pub bytes_received: u64,
}

/// What a download moved.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Received {
    pub objects: u64,
    pub bytes: u64,
}

/// A remote artifact cache: content-addressed objects under `cas/`, stage records under `ac/`
/// (Bazel's names: content-addressable storage, action cache).
pub struct Remote {
    name: String,
    url: String,
    bucket: Option<String>,
    inner: Box<dyn ObjectStore>,
    prefix: Vec<String>,
    runtime: tokio::runtime::Runtime,
    jobs: usize,
    /// A WebDAV server: directories (collections) exist apart from the files in them.
    collections: bool,
}

impl std::fmt::Debug for Remote {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Remote")
            .field("name", &self.name)
            .field("url", &self.url)
            .finish_non_exhaustive()
    }
}

impl Remote {
    /// Opens remote `name` at `url`: `s3://BUCKET[/PREFIX]` (credentials, region and endpoint
    /// from the standard `AWS_*` variables), `http(s)://HOST/PATH` (a WebDAV server) or
    /// `file:///PATH` (a directory, say on a cluster's shared filesystem). Nothing is contacted
    /// until a transfer or [`Remote::check`].
    pub fn open(name: &str, url: &str) -> Result<Remote> {
        let bad = |reason: String| Error::Url {
            remote: name.to_string(),
            url: redact(url),
            reason,
        };
        let parsed = url::Url::parse(url).map_err(|e| bad(e.to_string()))?;
        if !parsed.username().is_empty() || parsed.password().is_some() {
            return Err(bad(
                "credentials do not go into a URL (they would land in pipeline.toml and in logs); set them in the environment".to_string(),
            ));
        }
        let retry = RetryConfig {
            max_retries: 4,
            retry_timeout: Duration::from_secs(30),
            ..RetryConfig::default()
        };
        let segments = |path: &str| -> Vec<String> {
            path.split('/')
                .filter(|s| !s.is_empty())
                .map(str::to_string)
                .collect()
        };
        let (inner, prefix, bucket): (Box<dyn ObjectStore>, Vec<String>, Option<String>) =
            match parsed.scheme() {
                "s3" => {
                    let bucket = parsed
                        .host_str()
                        .filter(|b| !b.is_empty())
                        .ok_or_else(
                            || bad("an s3 URL names its bucket: s3://BUCKET/PREFIX".into()),
                        )?
                        .to_string();
                    let from_env = AmazonS3Builder::from_env();
                    // object_store unwraps the endpoint's parse deep in request signing: a
                    // variable set to nothing or to a host without a scheme must fail here.
                    if let Some(endpoint) = from_env.get_config_value(&AmazonS3ConfigKey::Endpoint)
                        && url::Url::parse(&endpoint).is_err()
                    {
                        return Err(bad(format!(
                            "AWS_ENDPOINT_URL is `{endpoint}`, not a URL: set it to the server's address, e.g. http://127.0.0.1:8333, or unset it for AWS"
                        )));
                    }
                    let store = from_env
                        .with_bucket_name(&bucket)
                        .with_config(
                            AmazonS3ConfigKey::Client(ClientConfigKey::ConnectTimeout),
                            "5s",
                        )
                        .with_retry(retry)
                        .build()
                        .map_err(|e| bad(e.to_string()))?;
                    (Box::new(store), segments(parsed.path()), Some(bucket))
                }
                "http" | "https" => {
                    // The store is rooted at the server and the URL's path is the prefix: a PUT
                    // whose collections are missing makes them (MKCOL) walking up from the
                    // object, but never the base URL's own path, which a fresh remote lacks.
                    let mut root = parsed.clone();
                    root.set_path("/");
                    let store = HttpBuilder::new()
                        .with_url(root.as_str())
                        .with_config(ClientConfigKey::ConnectTimeout, "5s")
                        .with_config(ClientConfigKey::AllowHttp, "true")
                        .with_retry(retry)
                        .build()
                        .map_err(|e| bad(e.to_string()))?;
                    (Box::new(store), segments(parsed.path()), None)
                }
                "file" => {
                    let dir = parsed.to_file_path().map_err(|()| {
                        bad("a file URL names an absolute path: file:///PATH".into())
                    })?;
                    std::fs::create_dir_all(&dir).map_err(|e| Error::Transfer {
                        remote: name.to_string(),
                        url: url.to_string(),
                        what: format!("creating {}", dir.display()),
                        detail: e.to_string(),
                    })?;
                    let store =
                        LocalFileSystem::new_with_prefix(&dir).map_err(|e| bad(e.to_string()))?;
                    (Box::new(store), Vec::new(), None)
                }
                other => {
                    return Err(bad(format!("unknown scheme `{other}`")));
                }
            };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .map_err(|e| bad(format!("cannot start the network runtime: {e}")))?;
        Ok(Remote {
            name: name.to_string(),
            url: redact(url),
            bucket,
            inner,
            prefix,
            runtime,
            jobs: DEFAULT_JOBS,
            collections: matches!(parsed.scheme(), "http" | "https"),
        })
    }

    /// Transfers at once (at least 1).
    #[must_use]
    pub fn with_jobs(mut self, jobs: usize) -> Remote {
        self.jobs = jobs.max(1);
        self
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn url(&self) -> &str {
        &self.url
    }

    fn path(&self, parts: &[&str]) -> Path {
        Path::from_iter(
            self.prefix
                .iter()
                .map(String::as_str)
                .chain(parts.iter().copied()),
        )
    }

    /// Where object `hash` lives on the remote: `cas/<first two hex digits>/<hash>`.
    pub fn object_path(&self, hash: &Hash) -> Path {
        let hex = hash.to_hex();
        self.path(&["cas", &hex[..2], &hex])
    }

    /// Where the record of stage key `key` lives: `ac/<first two hex digits>/<key>.json`.
    pub fn record_path(&self, key: &Hash) -> Path {
        let hex = key.to_hex();
        self.path(&["ac", &hex[..2], &format!("{hex}.json")])
    }

    /// Asks the remote for its record listing: a clear error now (unreachable, credentials,
    /// bucket) rather than a failed transfer later.
    pub fn check(&self) -> Result<()> {
        let ac = self.path(&["ac"]);
        self.runtime
            .block_on(self.inner.list_with_delimiter(Some(&ac)))
            .map(|_| ())
            .or_else(|e| match e {
                // A WebDAV or file remote that nothing was pushed to yet has no `ac/`.
                object_store::Error::NotFound { .. } => Ok(()),
                e => Err(self.error("listing its records", e)),
            })
    }

    /// Uploads every object the records name (outputs and parts), skipping those the remote
    /// holds, then the records: a record on the remote never names an object that is not there.
    /// Objects are read through the store's verified path, so a damaged local object is refused,
    /// never uploaded. Callers hold the store's lock, so `osms gc` waits for the push.
    pub fn push(
        &self,
        store: &Store,
        records: &[Record],
        progress: &dyn Progress,
    ) -> Result<PushReport> {
        let mut seen = BTreeSet::new();
        let objects: Vec<Hash> = records
            .iter()
            .flat_map(|r| std::iter::once(r.content_hash).chain(r.parts.iter().copied()))
            .filter(|h| seen.insert(*h))
            .collect();
        let local_size = |h: &Hash| std::fs::metadata(store.object_path(h)).map_or(0, |m| m.len());
        // An object the remote holds under its name is skipped, unless its size says it is not
        // the object (a damaged copy a push can mend without anyone deleting it by hand).
        let remote_sizes = self.parallel(&objects, |hash| self.size_of(hash))?;
        let missing: Vec<Hash> = objects
            .iter()
            .zip(&remote_sizes)
            .filter(|(h, size)| **size != Some(local_size(h)))
            .map(|(h, _)| *h)
            .collect();
        let sizes: u64 = missing.iter().map(local_size).sum();
        progress.begin("objects", missing.len() as u64, sizes);
        let sent = self.upload(
            &missing,
            |hash| hash.to_hex()[..2].to_string(),
            |hash| {
                let bytes = store.get(hash)?;
                let n = bytes.len() as u64;
                self.runtime
                    .block_on(
                        self.inner
                            .put(&self.object_path(hash), Bytes::from(bytes).into()),
                    )
                    .map_err(|e| self.error(&format!("uploading object {}", hash.short()), e))?;
                progress.advance(n);
                Ok(n)
            },
        )?;
        progress.end();
        self.upload(
            records,
            |record| record.key.to_hex()[..2].to_string(),
            |record| {
                let json = serde_json::to_vec_pretty(record).map_err(|e| Error::Transfer {
                    remote: self.name.clone(),
                    url: self.url.clone(),
                    what: format!("encoding the record of {}", record.key.short()),
                    detail: e.to_string(),
                })?;
                self.runtime
                    .block_on(
                        self.inner
                            .put(&self.record_path(&record.key), Bytes::from(json).into()),
                    )
                    .map_err(|e| self.error(&format!("uploading record {}", record.key.short()), e))
            },
        )?;
        Ok(PushReport {
            objects_sent: sent.len() as u64,
            bytes_sent: sent.iter().sum(),
            objects_present: (objects.len() - missing.len()) as u64,
            records: records.len() as u64,
        })
    }

    /// The record of stage key `key` on the remote, if any, read without downloading objects.
    pub fn record(&self, key: &Hash) -> Result<Option<Record>> {
        let path = self.record_path(key);
        let bytes = match self.runtime.block_on(async {
            let got = self.inner.get(&path).await?;
            got.bytes().await
        }) {
            Ok(b) => b,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(self.error(&format!("reading record {}", key.short()), e)),
        };
        let bad = |reason: String| Error::BadRecord {
            remote: self.name.clone(),
            url: self.url.clone(),
            key: *key,
            reason,
        };
        let record: Record = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
        if record.key != *key {
            return Err(bad(format!("it names key {}", record.key)));
        }
        Ok(Some(record))
    }

    /// Downloads what stage key `key` needs into `store` if the remote has it ([`Remote::download`]
    /// of its record). `None`: the remote has no record for the key. Callers hold the store's
    /// lock.
    pub fn fetch(
        &self,
        store: &Store,
        key: &Hash,
        progress: &dyn Progress,
    ) -> Result<Option<Fetched>> {
        let Some(record) = self.record(key)? else {
            return Ok(None);
        };
        let received = self.download(store, std::slice::from_ref(&record), progress)?;
        Ok(Some(Fetched {
            record,
            objects_received: received.objects,
            bytes_received: received.bytes,
        }))
    }

    /// Brings `records` (read from this remote with [`Remote::record`]) into `store`: every
    /// object they name that the store lacks, all at once, each checked against its blake3 name
    /// before it enters the store through one [`osms_store::Batch`] (temp files, a sync, renames);
    /// then the records, after the objects are durable. Callers hold the store's lock.
    pub fn download(
        &self,
        store: &Store,
        records: &[Record],
        progress: &dyn Progress,
    ) -> Result<Received> {
        // Each object once, with the first record that names it (for a message).
        let mut named_by: BTreeMap<Hash, Hash> = BTreeMap::new();
        for r in records {
            for h in std::iter::once(r.content_hash).chain(r.parts.iter().copied()) {
                named_by.entry(h).or_insert(r.key);
            }
        }
        let mut missing = Vec::new();
        for (hash, key) in named_by {
            if store.object_state_cached(&hash)? != ObjectState::Present {
                missing.push((hash, key));
            }
        }
        let expected: u64 = records.iter().map(|r| r.size_bytes).sum();
        progress.begin("objects", missing.len() as u64, expected);
        let batch = store.batch()?;
        let received = self.parallel(&missing, |(hash, key)| {
            let bytes = match self.runtime.block_on(async {
                let got = self.inner.get(&self.object_path(hash)).await?;
                got.bytes().await
            }) {
                Ok(b) => b,
                Err(object_store::Error::NotFound { .. }) => {
                    return Err(Error::MissingObject {
                        remote: self.name.clone(),
                        url: self.url.clone(),
                        key: *key,
                        object: *hash,
                    });
                }
                Err(e) => {
                    return Err(self.error(&format!("downloading object {}", hash.short()), e));
                }
            };
            let actual = Hash::of(&bytes);
            if actual != *hash {
                return Err(Error::Corrupt {
                    remote: self.name.clone(),
                    url: self.url.clone(),
                    object: *hash,
                    actual,
                });
            }
            batch.put(&bytes)?;
            progress.advance(bytes.len() as u64);
            Ok(bytes.len() as u64)
        })?;
        progress.end();
        batch.commit(records)?;
        Ok(Received {
            objects: received.len() as u64,
            bytes: received.iter().sum(),
        })
    }

    /// The size of object `hash` on the remote, if it is there.
    fn size_of(&self, hash: &Hash) -> Result<Option<u64>> {
        match self
            .runtime
            .block_on(self.inner.head(&self.object_path(hash)))
        {
            Ok(meta) => Ok(Some(meta.size)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.error(&format!("looking up object {}", hash.short()), e)),
        }
    }

    /// Uploads `items` with `f`, `jobs` at once. A WebDAV server makes a PUT's missing
    /// directories one MKCOL at a time and answers two racing MKCOLs of one directory with an
    /// error (rclone's server: 423 Locked), so there the first upload into each directory
    /// (`dir` of the item) goes alone, before the rest go in parallel.
    fn upload<T: Sync, R: Send>(
        &self,
        items: &[T],
        dir: impl Fn(&T) -> String,
        f: impl Fn(&T) -> Result<R> + Sync,
    ) -> Result<Vec<R>> {
        if !self.collections {
            return self.parallel(items, f);
        }
        let mut seen = BTreeSet::new();
        let (first, rest): (Vec<&T>, Vec<&T>) = items.iter().partition(|t| seen.insert(dir(t)));
        let mut out = Vec::with_capacity(items.len());
        for t in first {
            out.push(f(t)?);
        }
        out.extend(self.parallel(&rest, |t| f(t))?);
        Ok(out)
    }

    /// `f` over `items` on up to `jobs` threads, results in `items`' order; the first error
    /// (in item order) wins, and no new item starts once one failed.
    fn parallel<T: Sync, R: Send>(
        &self,
        items: &[T],
        f: impl Fn(&T) -> Result<R> + Sync,
    ) -> Result<Vec<R>> {
        let next = AtomicU64::new(0);
        let failed = std::sync::atomic::AtomicBool::new(false);
        let results: Mutex<Vec<Option<Result<R>>>> =
            Mutex::new((0..items.len()).map(|_| None).collect());
        std::thread::scope(|scope| {
            for _ in 0..self.jobs.min(items.len()) {
                scope.spawn(|| {
                    loop {
                        if failed.load(Ordering::Relaxed) {
                            break;
                        }
                        let k = next.fetch_add(1, Ordering::Relaxed) as usize;
                        let Some(item) = items.get(k) else { break };
                        let r = f(item);
                        if r.is_err() {
                            failed.store(true, Ordering::Relaxed);
                        }
                        results
                            .lock()
                            .unwrap_or_else(std::sync::PoisonError::into_inner)[k] = Some(r);
                    }
                });
            }
        });
        let results = results
            .into_inner()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let mut out = Vec::with_capacity(items.len());
        let mut first_error = None;
        for r in results {
            match r {
                Some(Ok(v)) => out.push(v),
                Some(Err(e)) => {
                    first_error.get_or_insert(e);
                }
                None => {}
            }
        }
        match first_error {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }

    /// An object_store error as the user should read it: which remote, and what to check.
    fn error(&self, what: &str, e: object_store::Error) -> Error {
        let remote = self.name.clone();
        let url = self.url.clone();
        let detail = chain(&e);
        // S3 names the cause in its XML body whatever the status; a missing bucket may come
        // back as 403 or 404.
        if detail.contains("NoSuchBucket") {
            return Error::NoBucket {
                remote,
                url,
                bucket: self.bucket.clone().unwrap_or_default(),
            };
        }
        let denied = matches!(
            e,
            object_store::Error::PermissionDenied { .. }
                | object_store::Error::Unauthenticated { .. }
        ) || [
            "InvalidAccessKeyId",
            "SignatureDoesNotMatch",
            "AccessDenied",
        ]
        .iter()
        .any(|code| detail.contains(code));
        if denied {
            Error::Denied {
                remote,
                url,
                detail,
            }
        } else if unreachable(&e) {
            Error::Unreachable {
                remote,
                url,
                detail,
            }
        } else {
            Error::Transfer {
                remote,
                url,
                what: what.to_string(),
                detail,
            }
        }
    }
}

/// Whether a connection never came about (refused, timed out, no route, unknown host).
fn unreachable(e: &(dyn std::error::Error + 'static)) -> bool {
    let mut source: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(s) = source {
        if let Some(r) = s.downcast_ref::<reqwest::Error>()
            && (r.is_connect() || r.is_timeout())
        {
            return true;
        }
        if let Some(io) = s.downcast_ref::<std::io::Error>()
            && matches!(
                io.kind(),
                std::io::ErrorKind::ConnectionRefused
                    | std::io::ErrorKind::TimedOut
                    | std::io::ErrorKind::HostUnreachable
                    | std::io::ErrorKind::NetworkUnreachable
            )
        {
            return true;
        }
        source = s.source();
    }
    false
}

/// An error and its causes on one line, each said once.
fn chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut source: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(s) = source {
        let text = s.to_string();
        if !parts.iter().any(|p| p.contains(&text)) {
            parts.push(text);
        }
        source = s.source();
    }
    parts.join(": ")
}

/// `url` without a user name or password, for messages.
fn redact(url: &str) -> String {
    match url::Url::parse(url) {
        Ok(mut u) if !u.username().is_empty() || u.password().is_some() => {
            let _ = u.set_username("");
            let _ = u.set_password(None);
            u.to_string()
        }
        _ => url.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(store: &Store, stage: &str, bytes: &[u8], parts: &[&[u8]]) -> Record {
        let content_hash = store.put(bytes).expect("put");
        let parts = parts.iter().map(|p| store.put(p).expect("put")).collect();
        let record = Record {
            key: Hash::of(stage.as_bytes()),
            content_hash,
            stage: stage.to_string(),
            kind: "test".to_string(),
            code_version: 1,
            seed: None,
            fold: None,
            shard: None,
            parts,
            params: serde_json::json!({}),
            inputs: Vec::new(),
            type_tag: "bytes".to_string(),
            size_bytes: bytes.len() as u64,
            osms_version: "0".to_string(),
            wall_time_secs: 0.0,
            cpu_secs: None,
        };
        store.put_record(&record).expect("put_record");
        record
    }

    /// A store holding one artifact (`b"an artifact"`, no parts) and a `file://` remote in
    /// `dir/remote` it was pushed to.
    fn pushed_one(dir: &std::path::Path) -> (Store, Record, std::path::PathBuf, Remote) {
        let from = Store::open(dir.join("from")).expect("store");
        let a = record(&from, "a", b"an artifact", &[]);
        let remote_dir = dir.join("remote");
        let remote = file_remote(&remote_dir);
        remote
            .push(&from, std::slice::from_ref(&a), &NoProgress)
            .expect("push");
        (from, a, remote_dir, remote)
    }

    fn file_remote(dir: &std::path::Path) -> Remote {
        let url = url::Url::from_directory_path(dir).expect("url").to_string();
        Remote::open("shared", &url).expect("open")
    }

    #[test]
    fn push_then_fetch_into_an_empty_store_gives_the_same_objects_and_records() {
        let tmp = tempfile::tempdir().expect("tmp");
        let from = Store::open(tmp.path().join("from")).expect("store");
        let a = record(&from, "a", b"first artifact", &[b"part one", b"part two"]);
        let b = record(&from, "b", b"second artifact", &[b"part one"]);
        let remote = file_remote(&tmp.path().join("remote"));
        remote.check().expect("check");
        let report = remote
            .push(&from, &[a.clone(), b.clone()], &NoProgress)
            .expect("push");
        assert_eq!(report.objects_sent, 4, "{report:?}");
        assert_eq!(report.objects_present, 0);
        assert_eq!(report.records, 2);
        // Pushed again, every object is skipped by name.
        let again = remote
            .push(&from, &[a.clone(), b.clone()], &NoProgress)
            .expect("push");
        assert_eq!((again.objects_sent, again.objects_present), (0, 4));

        let to = Store::open(tmp.path().join("to")).expect("store");
        let fetched = remote
            .fetch(&to, &a.key, &NoProgress)
            .expect("fetch")
            .expect("found");
        assert_eq!(fetched.record, a);
        assert_eq!(fetched.objects_received, 3);
        assert_eq!(to.get(&a.content_hash).expect("object"), b"first artifact");
        assert_eq!(to.record(&a.key).expect("record"), Some(a.clone()));
        // b's shared part is in the store already: only its own object moves.
        let fetched = remote
            .fetch(&to, &b.key, &NoProgress)
            .expect("fetch")
            .expect("found");
        assert_eq!(fetched.objects_received, 1);
        assert!(
            remote
                .fetch(&to, &Hash::of(b"never built"), &NoProgress)
                .expect("fetch")
                .is_none()
        );
    }

    #[test]
    fn a_damaged_object_on_the_remote_is_refused_and_nothing_is_stored() {
        let tmp = tempfile::tempdir().expect("tmp");
        let (from, a, dir, remote) = pushed_one(tmp.path());
        let on_disk = dir.join(remote.object_path(&a.content_hash).as_ref());
        std::fs::write(&on_disk, b"an artifacT").expect("damage");

        let to = Store::open(tmp.path().join("to")).expect("store");
        let err = remote.fetch(&to, &a.key, &NoProgress).expect_err("damaged");
        assert!(
            matches!(&err, Error::Corrupt { object, .. } if *object == a.content_hash),
            "{err}"
        );
        assert!(err.to_string().contains("remote `shared`"), "{err}");
        assert_eq!(
            to.object_state(&a.content_hash).expect("state"),
            ObjectState::Missing
        );
        assert_eq!(to.record(&a.key).expect("record"), None);
        // A copy of the wrong size (an interrupted upload by another tool, say) is mended by
        // the next push; one of the right size by removing it first, as the hint says.
        std::fs::write(&on_disk, b"trunc").expect("truncate");
        let mended = remote
            .push(&from, std::slice::from_ref(&a), &NoProgress)
            .expect("push");
        assert_eq!((mended.objects_sent, mended.objects_present), (1, 0));
        assert!(
            remote
                .fetch(&to, &a.key, &NoProgress)
                .expect("fetch")
                .is_some()
        );
        assert_eq!(to.get(&a.content_hash).expect("object"), b"an artifact");
    }

    #[test]
    fn a_record_without_its_object_or_under_another_key_is_an_error() {
        let tmp = tempfile::tempdir().expect("tmp");
        let (_from, a, dir, remote) = pushed_one(tmp.path());
        let to = Store::open(tmp.path().join("to")).expect("store");

        std::fs::remove_file(dir.join(remote.object_path(&a.content_hash).as_ref())).expect("rm");
        let err = remote
            .fetch(&to, &a.key, &NoProgress)
            .expect_err("no object");
        assert!(matches!(err, Error::MissingObject { .. }), "{err}");
        assert_eq!(to.record(&a.key).expect("record"), None);

        let other = Hash::of(b"other key");
        let moved = dir.join(remote.record_path(&other).as_ref());
        std::fs::create_dir_all(moved.parent().expect("parent")).expect("mkdir");
        std::fs::copy(dir.join(remote.record_path(&a.key).as_ref()), &moved).expect("copy");
        let err = remote
            .fetch(&to, &other, &NoProgress)
            .expect_err("wrong key");
        assert!(matches!(err, Error::BadRecord { .. }), "{err}");
    }

    #[test]
    fn urls_are_checked_and_never_carry_credentials() {
        let err = Remote::open("r", "s3://user:secret@bucket/p").expect_err("credentials");
        let text = err.to_string();
        assert!(
            text.contains("environment") && !text.contains("secret"),
            "{text}"
        );
        let err = Remote::open("r", "ftp://host/x").expect_err("scheme");
        assert!(err.to_string().contains("unknown scheme `ftp`"), "{err}");
        let err = Remote::open("r", "not a url").expect_err("url");
        assert!(err.to_string().contains("s3://BUCKET/PREFIX"), "{err}");
        let err = Remote::open("r", "file://relative/path").expect_err("relative");
        assert!(matches!(err, Error::Url { .. }), "{err}");
    }

    #[test]
    fn layout_is_cas_and_ac_under_the_prefix() {
        let remote = Remote::open("r", "s3://bucket/team/osms").expect("open");
        let h = Hash::of(b"x");
        let hex = h.to_hex();
        assert_eq!(
            remote.object_path(&h).as_ref(),
            format!("team/osms/cas/{}/{hex}", &hex[..2])
        );
        assert_eq!(
            remote.record_path(&h).as_ref(),
            format!("team/osms/ac/{}/{hex}.json", &hex[..2])
        );
    }
}
