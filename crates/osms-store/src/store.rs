//! The on-disk store.
//!
//! ```text
//! <root>/OSMS_STORE           layout marker; a directory without it is not touched
//! <root>/objects/ab/<hash>    artifact bytes, named by the blake3 of those bytes
//! <root>/index/ab/<key>.json  stage key -> content hash + metadata (a [`Record`])
//! <root>/state/<name>         small files owned by the engine (e.g. the last build of each stage)
//! <root>/tmp/                 writes in flight; emptied by whoever takes the lock
//! <root>/tmp/tasks/<name>/    writes in flight of one cluster task (see [`Store::for_task`])
//! <root>/lock                 advisory lock file serialising writers
//! ```
//!
//! Every write goes to `tmp/`, is fsynced, renamed into place, and the directory is fsynced, so
//! a crash at any point leaves either the old state or the new one, never a half-written file.
//! Every read re-hashes, so a damaged object is reported, never used.
//!
//! Cluster tasks write without the lock: each writes content-addressed objects (two writers of
//! one object write the same bytes, and a rename over it is harmless) and the records of its own
//! keys, through a temp directory of its own that the lock holder's clean-up leaves alone.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::{self, File, OpenOptions};
use std::io::{ErrorKind, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use osms_core::read_header;
use serde::{Deserialize, Serialize};

use crate::statcache::{Stamp, StatCache};
use crate::{Error, Hash, Result};

const MARKER: &str = "OSMS_STORE";
const MARKER_TEXT: &str = "osms store, layout 1\n";

/// What the engine records about one built artifact, keyed by its stage key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Record {
    pub key: Hash,
    pub content_hash: Hash,
    pub stage: String,
    pub kind: String,
    pub code_version: u32,
    /// `None` for stages that draw no random numbers.
    pub seed: Option<u64>,
    /// The fold of an instance of a stage declared with `folds`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fold: Option<u32>,
    /// Set on the records of shards of an itemised stage.
    pub shard: Option<ShardOf>,
    /// The objects the artifact refers to (the shards of a sharded stage's manifest): kept,
    /// verified and checked with it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub parts: Vec<Hash>,
    pub params: serde_json::Value,
    /// Input slot -> content hash, in slot order.
    pub inputs: Vec<(String, Hash)>,
    pub type_tag: String,
    pub size_bytes: u64,
    pub osms_version: String,
    pub wall_time_secs: f64,
    /// Core-seconds spent computing the artifact, its shards included (wall time times the
    /// threads it ran on, summed over the jobs of a cluster build): what `osms plan` scales.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_secs: Option<f64>,
}

impl Record {
    /// The instance it is a build of, as osms names it: `stage`, `stage#fold`, `stage@seed`,
    /// `stage#fold@seed`.
    pub fn instance(&self) -> String {
        let mut s = self.stage.clone();
        if let Some(f) = self.fold {
            s.push_str(&format!("#{f}"));
        }
        if let Some(seed) = self.seed {
            s.push_str(&format!("@{seed}"));
        }
        s
    }
}

/// Which stage a shard belongs to and which items `[start, end)` it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardOf {
    pub stage_key: Hash,
    pub start: u64,
    pub end: u64,
    /// Which of the stage's shards it is (its cluster array task).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index: Option<u32>,
}

/// The state of one object on disk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectState {
    Present,
    Missing,
    Damaged { actual: Hash },
}

/// Something `verify` found wrong.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "problem", rename_all = "snake_case")]
pub enum VerifyProblem {
    DamagedObject {
        hash: Hash,
        actual: Hash,
        path: PathBuf,
        /// The records whose output (or one of whose parts) it is, as `(stage, key)`: the
        /// stages `osms make` rebuilds.
        used_by: Vec<(String, Hash)>,
    },
    /// An object the filesystem would not read (EIO, say): not known to be damaged, but no
    /// stage can read it either.
    UnreadableObject {
        hash: Hash,
        path: PathBuf,
        error: String,
        /// As for damaged objects.
        used_by: Vec<(String, Hash)>,
    },
    ForeignObject {
        path: PathBuf,
        reason: String,
    },
    StrayFile {
        path: PathBuf,
    },
    MissingObject {
        key: Hash,
        stage: String,
        hash: Hash,
    },
    BadRecord {
        path: PathBuf,
        reason: String,
    },
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct VerifyReport {
    pub objects_checked: u64,
    pub bytes_checked: u64,
    pub records_checked: u64,
    pub problems: Vec<VerifyProblem>,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct GcReport {
    pub dry_run: bool,
    pub objects_removed: Vec<Hash>,
    pub bytes_removed: u64,
    pub records_removed: Vec<Hash>,
    pub objects_kept: u64,
}

/// An index file that did not parse, and why.
pub type UnreadableRecord = (PathBuf, String);

/// Held while a process may write to the store; released on drop. On a store that cannot be
/// written (a read-only mount, no write permission) it holds nothing: such a process can only
/// read, so it cannot race a writer; what it reads is what a writer had renamed into place,
/// whole, since every object and record is written through a temporary file.
#[derive(Debug)]
pub struct StoreLock {
    _file: Option<File>,
}

#[derive(Debug, Clone)]
pub struct Store {
    root: PathBuf,
    /// Where writes in flight go: `tmp/`, or a cluster task's own directory below it.
    tmp: PathBuf,
    stat_cache: Arc<Mutex<Option<StatCache>>>,
    /// Set when taking the lock found the store cannot be written.
    read_only: Arc<AtomicBool>,
}

const STAT_CACHE: &str = "statcache";
const TASKS: &str = "tasks";

/// This machine's host name, for messages about where a task ran.
pub fn host_name() -> String {
    static NAME: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    NAME.get_or_init(|| {
        fs::read_to_string("/proc/sys/kernel/hostname")
            .map(|s| s.trim().to_string())
            .ok()
            .filter(|s| !s.is_empty())
            .unwrap_or_else(|| "localhost".to_string())
    })
    .clone()
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl Store {
    /// Opens the store at `root`, creating it if the directory is absent or empty. A non-empty
    /// directory that is not an osms store is refused, so a mistyped `--store` cannot litter or
    /// garbage-collect someone's files.
    pub fn open(root: impl Into<PathBuf>) -> Result<Self> {
        let root = root.into();
        if root.exists() && !root.is_dir() {
            return Err(Error::Foreign {
                reason: format!("{} is a file, not an osms store directory", root.display()),
            });
        }
        let store = Store {
            tmp: root.join("tmp"),
            root,
            stat_cache: Arc::default(),
            read_only: Arc::default(),
        };
        let marker = store.root.join(MARKER);
        if !marker.is_file() {
            let empty = match fs::read_dir(&store.root) {
                Ok(mut entries) => entries.all(|e| {
                    e.map(|e| e.file_name().to_string_lossy().starts_with('.'))
                        .unwrap_or(false)
                }),
                Err(e) if e.kind() == ErrorKind::NotFound => true,
                Err(e) => return Err(Error::io(&store.root, e)),
            };
            // Another process may have created the store since the first look.
            if !empty && !marker.is_file() {
                return Err(Error::Foreign {
                    reason: format!(
                        "{} is a non-empty directory without an {MARKER} marker, so it is not \
                         an osms store; hint: choose an empty or new directory with --store",
                        store.root.display()
                    ),
                });
            }
            if empty {
                fs::create_dir_all(&store.root).map_err(|e| Error::io(&store.root, e))?;
                // The marker goes first, through a dot-file, so an interrupted or concurrent
                // creation never leaves a directory that looks foreign.
                store.write_beside(&marker, MARKER_TEXT.as_bytes())?;
            }
        }
        store.ensure_dirs()
    }

    /// Opens a store that must already exist: a cluster task on a node where the store's path
    /// is not the shared store would otherwise create an empty one there and compute into it.
    pub fn open_existing(root: impl Into<PathBuf>) -> Result<Self> {
        let root = root.into();
        if !root.join(MARKER).is_file() {
            return Err(Error::NotShared {
                root: root.clone(),
                host: host_name(),
            });
        }
        Self::open(root)
    }

    /// The same store, writing through `tmp/tasks/<name>/`: for a cluster task, whose writes
    /// must survive the lock holder's clean-up of `tmp/` while it runs. `name` identifies the
    /// task (its Slurm job id), so the driver can remove the directory once the task is gone.
    pub fn for_task(&self, name: &str) -> Result<Store> {
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
            || name.starts_with('.')
        {
            return Err(Error::Foreign {
                reason: format!(
                    "`{name}` is not a usable task name (letters, digits, `_`, `-`, `.`)"
                ),
            });
        }
        let tmp = self.root.join("tmp").join(TASKS).join(name);
        fs::create_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        Ok(Store {
            root: self.root.clone(),
            tmp,
            stat_cache: Arc::default(),
            read_only: Arc::default(),
        })
    }

    /// The names of the task directories under `tmp/tasks/`, sorted.
    pub fn task_dirs(&self) -> Result<Vec<String>> {
        sorted_names(&self.root.join("tmp").join(TASKS))
    }

    /// Removes a finished task's directory with whatever a kill left in it. Callers hold the
    /// lock and know the task is no longer running.
    pub fn remove_task_dir(&self, name: &str) -> Result<()> {
        let dir = self.root.join("tmp").join(TASKS).join(name);
        match fs::remove_dir_all(&dir) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == ErrorKind::NotFound => Ok(()),
            Err(e) => Err(Error::io(&dir, e)),
        }
    }

    fn ensure_dirs(self) -> Result<Self> {
        for dir in ["objects", "index", "state", "tmp"] {
            let path = self.root.join(dir);
            fs::create_dir_all(&path).map_err(|e| Error::io(&path, e))?;
        }
        Ok(self)
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn object_path(&self, hash: &Hash) -> PathBuf {
        let hex = hash.to_hex();
        self.root.join("objects").join(&hex[..2]).join(hex)
    }

    /// Where the index record of `key` lives.
    pub fn record_path(&self, key: &Hash) -> PathBuf {
        let hex = key.to_hex();
        self.root
            .join("index")
            .join(&hex[..2])
            .join(format!("{hex}.json"))
    }

    /// Takes the writer lock, waiting for another holder to finish, then empties `tmp/` (only a
    /// lock holder writes there, so anything in it is debris from a killed process).
    pub fn lock(&self, on_wait: impl FnOnce()) -> Result<StoreLock> {
        let path = self.root.join("lock");
        let file = match OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
        {
            Ok(file) => file,
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::ReadOnlyFilesystem | ErrorKind::PermissionDenied
                ) =>
            {
                self.read_only.store(true, Ordering::Relaxed);
                return Ok(StoreLock { _file: None });
            }
            Err(e) => return Err(Error::io(&path, e)),
        };
        match file.try_lock() {
            Ok(()) => {}
            Err(fs::TryLockError::WouldBlock) => {
                on_wait();
                file.lock().map_err(|e| Error::io(&path, e))?;
            }
            Err(fs::TryLockError::Error(e)) => return Err(Error::io(&path, e)),
        }
        self.clear_tmp()?;
        Ok(StoreLock { _file: Some(file) })
    }

    /// Removes the files in `tmp/`; the task directories below it belong to cluster tasks that
    /// may still be running.
    fn clear_tmp(&self) -> Result<()> {
        let tmp = self.root.join("tmp");
        let entries = fs::read_dir(&tmp).map_err(|e| Error::io(&tmp, e))?;
        for entry in entries {
            let entry = entry.map_err(|e| Error::io(&tmp, e))?;
            if entry.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                continue;
            }
            let path = entry.path();
            match fs::remove_file(&path) {
                Ok(()) => {}
                Err(e) if e.kind() == ErrorKind::NotFound => {}
                Err(e) => return Err(Error::io(&path, e)),
            }
        }
        Ok(())
    }

    /// Writes `bytes` to `dest` through a temp file in `tmp/`. Only for lock holders: taking the
    /// lock empties `tmp/`.
    fn write_atomic(&self, dest: &Path, bytes: &[u8]) -> Result<()> {
        let tmp_dir = &self.tmp;
        fs::create_dir_all(tmp_dir).map_err(|e| Error::io(tmp_dir, e))?;
        let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        write_via(
            // Tasks on several hosts may share a directory name space: the host keeps their
            // temp names apart.
            &tmp_dir.join(format!("{}-{}-{n}", host_name(), std::process::id())),
            dest,
            bytes,
        )
    }

    /// Like `write_atomic`, for writers that do not hold the lock: the temp file is a dot-file
    /// beside `dest`, out of reach of the lock holder's clean-up of `tmp/`.
    fn write_beside(&self, dest: &Path, bytes: &[u8]) -> Result<()> {
        let dir = dest.parent().expect("store paths have a parent");
        let name = dest
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        write_via(
            &dir.join(format!(".{name}.tmp-{}-{n}", std::process::id())),
            dest,
            bytes,
        )
    }

    /// Stores `bytes` and returns their content hash. An intact copy already present is kept;
    /// a damaged one is replaced.
    pub fn put(&self, bytes: &[u8]) -> Result<Hash> {
        let hash = Hash::of(bytes);
        if self.object_state(&hash)? != ObjectState::Present {
            self.write_atomic(&self.object_path(&hash), bytes)?;
        }
        Ok(hash)
    }

    /// A writer of many objects and then their records at the cost of three filesystem syncs
    /// instead of two per file (a pull of the small profile's 4,030 files took 1.95 s with a
    /// sync per file, 1.42 s batched), with the same guarantees as [`Store::put`] and
    /// [`Store::put_record`]: see [`Batch`]. Callers hold the lock.
    pub fn batch(&self) -> Result<Batch<'_>> {
        fs::create_dir_all(&self.tmp).map_err(|e| Error::io(&self.tmp, e))?;
        Ok(Batch {
            store: self,
            staged: Mutex::new(Vec::new()),
        })
    }

    /// Removes the object `hash` if no record names it (as output or part): for objects a
    /// build superseded itself, such as its previous checkpoint, which would otherwise wait
    /// for `osms gc`. Whether it was removed. Callers hold the lock.
    pub fn remove_if_unreferenced(&self, hash: &Hash) -> Result<bool> {
        let (records, unreadable) = self.records()?;
        // An unreadable record might name it: keep it for gc, which sees the same.
        if !unreadable.is_empty()
            || records
                .iter()
                .any(|r| r.content_hash == *hash || r.parts.contains(hash))
        {
            return Ok(false);
        }
        let path = self.object_path(hash);
        match fs::remove_file(&path) {
            Ok(()) => Ok(true),
            Err(e) if e.kind() == ErrorKind::NotFound => Ok(false),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// Reads an object and checks its bytes against its name.
    pub fn get(&self, hash: &Hash) -> Result<Vec<u8>> {
        let path = self.object_path(hash);
        let bytes = match fs::read(&path) {
            Ok(b) => b,
            Err(e) if e.kind() == ErrorKind::NotFound => {
                return Err(Error::Missing { hash: *hash });
            }
            Err(e) => return Err(Error::io(&path, e)),
        };
        let actual = Hash::of(&bytes);
        if actual != *hash {
            return Err(Error::Damaged {
                hash: *hash,
                actual,
                path,
            });
        }
        Ok(bytes)
    }

    pub fn object_state(&self, hash: &Hash) -> Result<ObjectState> {
        match self.get(hash) {
            Ok(_) => Ok(ObjectState::Present),
            Err(Error::Missing { .. }) => Ok(ObjectState::Missing),
            Err(Error::Damaged { actual, .. }) => Ok(ObjectState::Damaged { actual }),
            Err(e) => Err(e),
        }
    }

    /// Like [`Store::object_state`], but trusts an object verified before whose file metadata
    /// has not changed since (see `statcache.rs`). For deciding whether a cached artifact can be
    /// reused; reading an object's bytes always re-hashes them.
    pub fn object_state_cached(&self, hash: &Hash) -> Result<ObjectState> {
        let path = self.object_path(hash);
        let stamp = match fs::metadata(&path) {
            Ok(meta) => Stamp::of(&meta),
            Err(e) if e.kind() == ErrorKind::NotFound => return Ok(ObjectState::Missing),
            Err(e) => return Err(Error::io(&path, e)),
        };
        let mut guard = self.stat_cache.lock().unwrap_or_else(|p| p.into_inner());
        let cache = guard.get_or_insert_with(|| self.load_stat_cache());
        if cache.trusts(hash, &stamp) {
            return Ok(ObjectState::Present);
        }
        let state = self.object_state(hash)?;
        match state {
            ObjectState::Present => cache.verified(*hash, stamp),
            _ => cache.forget(hash),
        }
        Ok(state)
    }

    fn load_stat_cache(&self) -> StatCache {
        self.read_state(STAT_CACHE)
            .ok()
            .flatten()
            .map(|b| StatCache::from_bytes(&b))
            .unwrap_or_default()
    }

    /// Forgets that an object was verified, so the next [`Store::object_state_cached`]
    /// re-hashes it (its bytes were found damaged although its metadata did not change).
    pub fn distrust(&self, hash: &Hash) {
        let mut guard = self.stat_cache.lock().unwrap_or_else(|p| p.into_inner());
        guard
            .get_or_insert_with(|| self.load_stat_cache())
            .forget(hash);
    }

    /// Whether taking the lock found that this store cannot be written (a read-only mount, no
    /// write permission): it serves reads, and nothing can be built into it.
    pub fn is_read_only(&self) -> bool {
        self.read_only.load(Ordering::Relaxed)
    }

    /// Saves what [`Store::object_state_cached`] learnt, if it can: losing an update (two
    /// processes saving at once, a full disk, a read-only store) only costs a re-hash later.
    /// Returns whether it was saved (or had nothing to save).
    pub fn save_stat_cache(&self) -> bool {
        let guard = self.stat_cache.lock().unwrap_or_else(|p| p.into_inner());
        match guard.as_ref() {
            // `status` saves it without holding the lock.
            Some(cache) if cache.is_dirty() => self
                .write_beside(&self.root.join("state").join(STAT_CACHE), &cache.to_bytes())
                .is_ok(),
            _ => true,
        }
    }

    pub fn put_record(&self, record: &Record) -> Result<()> {
        let mut text = serde_json::to_vec_pretty(record).expect("records serialise to JSON");
        text.push(b'\n');
        self.write_atomic(&self.record_path(&record.key), &text)
    }

    pub fn record(&self, key: &Hash) -> Result<Option<Record>> {
        let path = self.record_path(key);
        match fs::read(&path) {
            Ok(bytes) => parse_record(&path, &bytes).map(Some),
            Err(e) if e.kind() == ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// All records in key order, with the ones that failed to parse reported separately.
    pub fn records(&self) -> Result<(Vec<Record>, Vec<UnreadableRecord>)> {
        let mut good = Vec::new();
        let mut bad = Vec::new();
        for path in sorted_files(&self.root.join("index"))? {
            let bytes = fs::read(&path).map_err(|e| Error::io(&path, e))?;
            match parse_record(&path, &bytes) {
                Ok(r) => good.push(r),
                Err(Error::BadRecord { path, reason }) => bad.push((path, reason)),
                Err(e) => return Err(e),
            }
        }
        good.sort_by_key(|r| r.key);
        Ok((good, bad))
    }

    pub fn read_state(&self, name: &str) -> Result<Option<Vec<u8>>> {
        let path = self.root.join("state").join(name);
        match fs::read(&path) {
            Ok(b) => Ok(Some(b)),
            Err(e) if e.kind() == ErrorKind::NotFound => Ok(None),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// Names of the state files directly inside `state/<dir>/`, sorted.
    pub fn list_state(&self, dir: &str) -> Result<Vec<String>> {
        sorted_names(&self.root.join("state").join(dir))
    }

    /// Replaces a state file. Callers hold the lock.
    pub fn write_state(&self, name: &str, bytes: &[u8]) -> Result<()> {
        self.write_atomic(&self.root.join("state").join(name), bytes)
    }

    /// Removes a state file, if it exists. Callers hold the lock.
    pub fn remove_state(&self, name: &str) -> Result<()> {
        let path = self.root.join("state").join(name);
        match fs::remove_file(&path) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == ErrorKind::NotFound => Ok(()),
            Err(e) => Err(Error::io(&path, e)),
        }
    }

    /// The path of a state file or directory (for logs that other programs write).
    pub fn state_path(&self, name: &str) -> PathBuf {
        self.root.join("state").join(name)
    }

    /// Re-hashes every object, checks every record's object exists and reports anything that
    /// does not belong.
    pub fn verify(&self) -> Result<VerifyReport> {
        let mut report = VerifyReport::default();
        let mut intact = BTreeSet::new();
        for path in sorted_files(&self.root.join("objects"))? {
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let Ok(hash) = name.parse::<Hash>() else {
                report.problems.push(VerifyProblem::StrayFile { path });
                continue;
            };
            let bytes = match fs::read(&path) {
                Ok(bytes) => bytes,
                Err(e) => {
                    report.problems.push(VerifyProblem::UnreadableObject {
                        hash,
                        path,
                        error: e.to_string(),
                        used_by: Vec::new(),
                    });
                    continue;
                }
            };
            report.objects_checked += 1;
            report.bytes_checked += bytes.len() as u64;
            let actual = Hash::of(&bytes);
            if actual != hash {
                report.problems.push(VerifyProblem::DamagedObject {
                    hash,
                    actual,
                    path,
                    used_by: Vec::new(),
                });
            } else if let Err(e) = read_header(&bytes) {
                report.problems.push(VerifyProblem::ForeignObject {
                    path,
                    reason: e.to_string(),
                });
            } else {
                intact.insert(hash);
            }
        }
        // Damaged object -> the records it belongs to, filled in below.
        let mut damaged: BTreeMap<Hash, Vec<(String, Hash)>> = report
            .problems
            .iter()
            .filter_map(|p| match p {
                VerifyProblem::DamagedObject { hash, .. }
                | VerifyProblem::UnreadableObject { hash, .. } => Some((*hash, Vec::new())),
                _ => None,
            })
            .collect();
        let (records, bad) = self.records()?;
        report.records_checked = (records.len() + bad.len()) as u64;
        for (path, reason) in bad {
            report
                .problems
                .push(VerifyProblem::BadRecord { path, reason });
        }
        for r in &records {
            for hash in std::iter::once(&r.content_hash).chain(&r.parts) {
                if let Some(users) = damaged.get_mut(hash) {
                    users.push((r.stage.clone(), r.key));
                }
                if !intact.contains(hash) && !self.object_path(hash).exists() {
                    report.problems.push(VerifyProblem::MissingObject {
                        key: r.key,
                        stage: r.stage.clone(),
                        hash: *hash,
                    });
                }
            }
        }
        for p in &mut report.problems {
            if let VerifyProblem::DamagedObject { hash, used_by, .. }
            | VerifyProblem::UnreadableObject { hash, used_by, .. } = p
            {
                *used_by = damaged.remove(hash).unwrap_or_default();
                // `make` must not take the stat cache's word for it: bit rot under the
                // filesystem (a failing disk) leaves the file's metadata as it was.
                self.distrust(hash);
            }
        }
        // Best effort: where it cannot be saved (a read-only store), nothing is built either.
        self.save_stat_cache();
        Ok(report)
    }

    /// Keeps the records whose keys are in `keep` and the objects they point to, plus the shards
    /// of every stage key in `planned` that has no kept record of its own, so a make interrupted
    /// mid-stage resumes from its finished shards; removes the rest. A stage whose record is kept
    /// is complete: its shard records go, and the shard objects stay as the parts of its record.
    /// Callers hold the lock.
    ///
    /// `keep` holds the keys whose artifacts are current, `planned` every stage key the
    /// pipeline can compute now (current or not): a stage still to be built has no record yet,
    /// so only its key says its shards are wanted.
    pub fn gc(
        &self,
        keep: &BTreeSet<Hash>,
        planned: &BTreeSet<Hash>,
        dry_run: bool,
    ) -> Result<GcReport> {
        let mut report = GcReport {
            dry_run,
            ..GcReport::default()
        };
        let (records, _) = self.records()?;
        let complete: BTreeSet<Hash> = records
            .iter()
            .filter(|r| r.shard.is_none() && keep.contains(&r.key))
            .map(|r| r.key)
            .collect();
        let kept = |r: &Record| match r.shard {
            Some(s) => planned.contains(&s.stage_key) && !complete.contains(&s.stage_key),
            None => keep.contains(&r.key),
        };
        let mut live = BTreeSet::new();
        for r in &records {
            if kept(r) {
                live.insert(r.content_hash);
                live.extend(r.parts.iter().copied());
            } else {
                report.records_removed.push(r.key);
                if !dry_run {
                    let path = self.record_path(&r.key);
                    fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
                }
            }
        }
        for path in sorted_files(&self.root.join("objects"))? {
            let name = path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let Ok(hash) = name.parse::<Hash>() else {
                continue;
            };
            if live.contains(&hash) {
                report.objects_kept += 1;
                continue;
            }
            report.bytes_removed += fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
            report.objects_removed.push(hash);
            if !dry_run {
                fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
            }
        }
        Ok(report)
    }
}

/// Objects written by [`Store::batch`]: each goes to `tmp/` unsynced; [`Batch::commit`] makes
/// them durable with one sync, renames them into place, writes the records the same way and
/// syncs again before and after renaming those. So an object's final name never holds a partial
/// file, and a record never reaches the disk before the objects it names. A batch dropped without
/// commit leaves its files in `tmp/`, which the next lock holder empties.
pub struct Batch<'a> {
    store: &'a Store,
    staged: Mutex<Vec<(PathBuf, PathBuf)>>,
}

impl Batch<'_> {
    /// Stages `bytes` and returns their content hash; an intact copy already in the store is
    /// kept (and nothing staged). Safe to call from several threads.
    pub fn put(&self, bytes: &[u8]) -> Result<Hash> {
        let hash = Hash::of(bytes);
        if self.store.object_state(&hash)? != ObjectState::Present {
            let dest = self.store.object_path(&hash);
            let tmp = self.stage(bytes)?;
            self.staged
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .push((tmp, dest));
        }
        Ok(hash)
    }

    fn stage(&self, bytes: &[u8]) -> Result<PathBuf> {
        let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = self
            .store
            .tmp
            .join(format!("{}-{}-{n}", host_name(), std::process::id()));
        let mut file = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        file.write_all(bytes).map_err(|e| Error::io(&tmp, e))?;
        Ok(tmp)
    }

    /// Makes the staged objects durable and puts them in place, then does the same for
    /// `records`: after it returns, both survive a crash.
    pub fn commit(self, records: &[Record]) -> Result<()> {
        let objects = std::mem::take(
            &mut *self
                .staged
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        );
        let root = &self.store.root;
        if !objects.is_empty() {
            syncfs(root)?;
            rename_all(&objects)?;
        }
        if records.is_empty() {
            return Ok(());
        }
        let mut staged = Vec::with_capacity(records.len());
        for record in records {
            let mut text = serde_json::to_vec_pretty(record).expect("records serialise to JSON");
            text.push(b'\n');
            staged.push((self.stage(&text)?, self.store.record_path(&record.key)));
        }
        // One sync covers the objects' renames and the records' bytes.
        syncfs(root)?;
        rename_all(&staged)?;
        syncfs(root)
    }
}

fn rename_all(moves: &[(PathBuf, PathBuf)]) -> Result<()> {
    for (tmp, dest) in moves {
        let dir = dest.parent().expect("store paths have a parent");
        fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        fs::rename(tmp, dest).map_err(|e| Error::io(dest, e))?;
    }
    Ok(())
}

/// Makes everything written so far on the filesystem that holds `root` durable, file data and
/// renames alike (Linux's `syncfs`; osms runs on Linux only, like MuJoCo's builds it links).
/// The workspace denies `unsafe_code`; `syncfs(2)` has no safe wrapper in std.
#[allow(unsafe_code)]
fn syncfs(root: &Path) -> Result<()> {
    use std::os::fd::AsRawFd;
    let dir = File::open(root).map_err(|e| Error::io(root, e))?;
    // SAFETY: `dir` is an open descriptor for the duration of the call.
    if unsafe { libc::syncfs(dir.as_raw_fd()) } != 0 {
        return Err(Error::io(root, std::io::Error::last_os_error()));
    }
    Ok(())
}

/// Writes `bytes` to `tmp`, fsyncs it, renames it to `dest` and fsyncs the directory, so a crash
/// leaves the old file or the new one, never a partial one.
fn write_via(tmp: &Path, dest: &Path, bytes: &[u8]) -> Result<()> {
    let dir = dest.parent().expect("store paths have a parent");
    fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let result = (|| {
        let mut file = File::create(tmp).map_err(|e| Error::io(tmp, e))?;
        file.write_all(bytes).map_err(|e| Error::io(tmp, e))?;
        file.sync_all().map_err(|e| Error::io(tmp, e))?;
        fs::rename(tmp, dest).map_err(|e| Error::io(dest, e))?;
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(|e| Error::io(dir, e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(tmp);
    }
    result
}

fn parse_record(path: &Path, bytes: &[u8]) -> Result<Record> {
    serde_json::from_slice(bytes).map_err(|e| Error::BadRecord {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// The names of the entries directly inside `dir`, sorted; none if it does not exist.
fn sorted_names(dir: &Path) -> Result<Vec<String>> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        names.push(entry.file_name().to_string_lossy().into_owned());
    }
    names.sort();
    Ok(names)
}

/// Files two levels below `dir` (`dir/ab/file`), sorted, so reports come out in a stable order.
fn sorted_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let top = match fs::read_dir(dir) {
        Ok(t) => t,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(out),
        Err(e) => return Err(Error::io(dir, e)),
    };
    for entry in top {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let path = entry.path();
        if path.is_dir() {
            for inner in fs::read_dir(&path).map_err(|e| Error::io(&path, e))? {
                out.push(inner.map_err(|e| Error::io(&path, e))?.path());
            }
        } else {
            out.push(path);
        }
    }
    out.sort();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use osms_core::{Artifact, encode};

    #[derive(Serialize, Deserialize)]
    struct Blob(Vec<u32>);
    impl Artifact for Blob {
        const TYPE_TAG: &'static str = "test-blob";
        const SCHEMA_VERSION: u16 = 1;
    }

    fn record(key: Hash, content_hash: Hash) -> Record {
        Record {
            key,
            content_hash,
            stage: "s".into(),
            kind: "k".into(),
            code_version: 1,
            seed: Some(0),
            fold: None,
            shard: None,
            parts: vec![],
            params: serde_json::json!({"n": 3}),
            inputs: vec![],
            type_tag: "test-blob".into(),
            size_bytes: 0,
            osms_version: "0".into(),
            wall_time_secs: 0.0,
            cpu_secs: None,
        }
    }

    #[test]
    fn put_get_round_trip_and_damage_detection() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path().join("s")).expect("open");
        let bytes = encode(&Blob((0..100).collect())).expect("encode");
        let hash = store.put(&bytes).expect("put");
        assert_eq!(hash, Hash::of(&bytes));
        assert_eq!(store.get(&hash).expect("get"), bytes);

        let path = store.object_path(&hash);
        let mut damaged = bytes.clone();
        damaged[20] ^= 1;
        fs::write(&path, &damaged).expect("write");
        assert!(matches!(store.get(&hash), Err(Error::Damaged { .. })));
        let report = store.verify().expect("verify");
        assert!(matches!(
            report.problems[..],
            [VerifyProblem::DamagedObject { .. }]
        ));

        // Putting the same bytes again repairs the damaged copy.
        store.put(&bytes).expect("put");
        assert_eq!(store.get(&hash).expect("get"), bytes);
        assert!(store.verify().expect("verify").problems.is_empty());

        fs::remove_file(&path).expect("remove");
        assert!(matches!(store.get(&hash), Err(Error::Missing { .. })));
    }

    #[test]
    fn a_batch_places_objects_then_records_and_an_uncommitted_one_places_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path().join("s")).expect("open");
        let blobs: Vec<Vec<u8>> = (0..20u32)
            .map(|n| encode(&Blob(vec![n; n as usize + 1])).expect("encode"))
            .collect();
        let kept = store.put(&blobs[0]).expect("put");

        let batch = store.batch().expect("batch");
        let hashes: Vec<Hash> = blobs.iter().map(|b| batch.put(b).expect("stage")).collect();
        assert_eq!(hashes[0], kept);
        // Staged, not placed: neither an object under its name nor a record yet.
        assert!(matches!(store.get(&hashes[5]), Err(Error::Missing { .. })));
        let records: Vec<Record> = hashes
            .iter()
            .enumerate()
            .map(|(i, h)| record(Hash::of(&[i as u8]), *h))
            .collect();
        batch.commit(&records).expect("commit");
        for (bytes, hash) in blobs.iter().zip(&hashes) {
            assert_eq!(&store.get(hash).expect("get"), bytes);
        }
        for r in &records {
            assert_eq!(store.record(&r.key).expect("read").as_ref(), Some(r));
        }
        assert!(store.verify().expect("verify").problems.is_empty());

        // A batch dropped before its commit (a killed pull) leaves its bytes in tmp/ only,
        // which the next lock holder empties.
        let lost = encode(&Blob(vec![99; 3])).expect("encode");
        let batch = store.batch().expect("batch");
        let hash = batch.put(&lost).expect("stage");
        drop(batch);
        assert!(matches!(store.get(&hash), Err(Error::Missing { .. })));
        assert!(fs::read_dir(dir.path().join("s/tmp")).expect("tmp").count() > 0);
        let _lock = store.lock(|| {}).expect("lock");
        assert_eq!(
            fs::read_dir(dir.path().join("s/tmp")).expect("tmp").count(),
            0
        );
        assert!(store.verify().expect("verify").problems.is_empty());
    }

    #[test]
    fn only_objects_no_record_names_are_removed() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path().join("s")).expect("open");
        let put = |n: u32| {
            store
                .put(&encode(&Blob(vec![n])).expect("encode"))
                .expect("put")
        };
        let (output, part, loose) = (put(1), put(2), put(3));
        let mut r = record(Hash::of(b"key"), output);
        r.parts = vec![part];
        store.put_record(&r).expect("record");
        for named in [output, part] {
            assert!(!store.remove_if_unreferenced(&named).expect("scan"));
            assert!(store.get(&named).is_ok());
        }
        assert!(store.remove_if_unreferenced(&loose).expect("scan"));
        assert!(matches!(store.get(&loose), Err(Error::Missing { .. })));
        assert!(!store.remove_if_unreferenced(&loose).expect("already gone"));
    }

    /// Bit rot below the filesystem leaves an object's metadata as it was, so the stat cache
    /// would go on vouching for it; once `verify` has seen the damage, it no longer does, and
    /// verify names the stage whose output the object is.
    #[test]
    fn what_verify_finds_damaged_the_stat_cache_no_longer_vouches_for() {
        let dir = tempfile::tempdir().expect("tempdir");
        let root = dir.path().join("s");
        let store = Store::open(&root).expect("open");
        let bytes = encode(&Blob((0..100).collect())).expect("encode");
        let hash = store.put(&bytes).expect("put");
        let key = Hash::of(b"key");
        store.put_record(&record(key, hash)).expect("record");
        let path = store.object_path(&hash);
        let mut damaged = bytes.clone();
        damaged[20] ^= 1;
        fs::write(&path, &damaged).expect("write");
        // The rot as a disk would do it: the cache holds the file's stamp as it is now, as if
        // it had been verified before the bytes changed under it.
        let stamp = Stamp::of(&fs::metadata(&path).expect("stat"));
        let mut cache = StatCache::default();
        cache.entries.insert(hash, stamp);
        store
            .write_beside(&root.join("state").join(STAT_CACHE), &cache.to_bytes())
            .expect("write the cache");
        let vouched = Store::open(&root).expect("open");
        assert_eq!(
            vouched.object_state_cached(&hash).expect("state"),
            ObjectState::Present,
            "the scenario: the cache vouches for the rotten object"
        );

        let report = Store::open(&root).expect("open").verify().expect("verify");
        match &report.problems[..] {
            [VerifyProblem::DamagedObject { used_by, .. }] => {
                assert_eq!(used_by, &[("s".to_string(), key)]);
            }
            other => panic!("{other:?}"),
        }
        let after = Store::open(&root).expect("open");
        assert!(matches!(
            after.object_state_cached(&hash).expect("state"),
            ObjectState::Damaged { .. }
        ));
    }

    #[test]
    fn refuses_non_store_directory_and_reports_foreign_objects() {
        let dir = tempfile::tempdir().expect("tempdir");
        fs::write(dir.path().join("notes.txt"), "mine").expect("write");
        assert!(matches!(
            Store::open(dir.path()),
            Err(Error::Foreign { .. })
        ));

        let store = Store::open(dir.path().join("s")).expect("open");
        let junk = b"not an artifact";
        let hash = Hash::of(junk);
        let path = store.object_path(&hash);
        fs::create_dir_all(path.parent().expect("parent")).expect("mkdir");
        fs::write(&path, junk).expect("write");
        fs::write(path.with_file_name("README"), "stray").expect("write");
        let problems = store.verify().expect("verify").problems;
        assert_eq!(problems.len(), 2, "{problems:?}");
    }

    #[test]
    fn records_gc_and_missing_objects() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        let a = store
            .put(&encode(&Blob(vec![1])).expect("encode"))
            .expect("put");
        let b = store
            .put(&encode(&Blob(vec![2])).expect("encode"))
            .expect("put");
        let (ka, kb) = (Hash::of(b"key a"), Hash::of(b"key b"));
        store.put_record(&record(ka, a)).expect("record");
        store.put_record(&record(kb, b)).expect("record");
        assert_eq!(store.record(&ka).expect("read"), Some(record(ka, a)));
        assert_eq!(store.records().expect("records").0.len(), 2);

        let keep: BTreeSet<Hash> = [ka].into();
        let dry = store.gc(&keep, &keep, true).expect("gc");
        assert_eq!(
            (dry.objects_removed.clone(), dry.records_removed.clone()),
            (vec![b], vec![kb])
        );
        assert_eq!(store.object_state(&b).expect("state"), ObjectState::Present);
        store.gc(&keep, &keep, false).expect("gc");
        assert_eq!(store.object_state(&b).expect("state"), ObjectState::Missing);
        assert_eq!(store.record(&kb).expect("read"), None);
        assert_eq!(store.object_state(&a).expect("state"), ObjectState::Present);

        fs::remove_file(store.object_path(&a)).expect("remove");
        let problems = store.verify().expect("verify").problems;
        assert!(matches!(
            problems[..],
            [VerifyProblem::MissingObject { .. }]
        ));
    }

    #[test]
    fn gc_keeps_the_shards_of_planned_stages_until_they_are_complete() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        let mut n = 0;
        let mut put = |store: &Store| {
            n += 1;
            store
                .put(&encode(&Blob(vec![n])).expect("encode"))
                .expect("put")
        };
        let shard = |store: &Store, stage_key: Hash, start: u64, content_hash: Hash| {
            let key = Hash::of(format!("{stage_key} {start}").as_bytes());
            let mut r = record(key, content_hash);
            r.shard = Some(ShardOf {
                stage_key,
                start,
                end: start + 1,
                index: None,
            });
            store.put_record(&r).expect("record");
            key
        };
        let [interrupted, complete, outdated, not_current] =
            ["interrupted", "complete", "outdated", "not current"].map(|s| Hash::of(s.as_bytes()));
        // Two shards of a stage the plan computes but that was killed before it finished.
        let resumable = [
            shard(&store, interrupted, 0, put(&store)),
            shard(&store, interrupted, 1, put(&store)),
        ];
        // A finished stage: its artifact holds every item, so its shards are dead weight.
        let done = put(&store);
        store.put_record(&record(complete, done)).expect("record");
        let done_shard = shard(&store, complete, 0, put(&store));
        // A shard of a stage the pipeline no longer computes (e.g. its params changed).
        let outdated_shard = shard(&store, outdated, 0, put(&store));
        // A finished stage whose record gc drops because its artifact is not current (in osms:
        // the object is damaged or missing): the stage is unfinished again, and its shards let
        // the next make rebuild it without recomputing them.
        let not_current_output = put(&store);
        store
            .put_record(&record(not_current, not_current_output))
            .expect("record");
        let rescue_shard = shard(&store, not_current, 0, put(&store));
        let shard_objects = |keys: &[Hash]| -> Vec<Hash> {
            keys.iter()
                .map(|k| store.record(k).expect("read").expect("record").content_hash)
                .collect()
        };
        let kept_objects = shard_objects(&[resumable[0], resumable[1], rescue_shard]);
        let removed_objects = shard_objects(&[done_shard, outdated_shard]);

        let keep: BTreeSet<Hash> = [complete].into();
        let planned: BTreeSet<Hash> = [interrupted, complete, not_current].into();
        let report = store.gc(&keep, &planned, false).expect("gc");
        let mut removed = vec![done_shard, outdated_shard, not_current];
        removed.sort();
        assert_eq!(report.records_removed, removed);
        let mut gone = removed_objects.clone();
        gone.push(not_current_output);
        gone.sort();
        assert_eq!(report.objects_removed, gone);
        for key in [resumable[0], resumable[1], rescue_shard, complete] {
            assert!(store.record(&key).expect("read").is_some(), "{key}");
        }
        for hash in kept_objects.into_iter().chain([done]) {
            assert_eq!(
                store.object_state(&hash).expect("state"),
                ObjectState::Present
            );
        }
        for hash in removed_objects {
            assert_eq!(
                store.object_state(&hash).expect("state"),
                ObjectState::Missing
            );
        }
    }

    #[test]
    fn cached_state_still_sees_damage_after_the_object_was_trusted() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        let bytes = encode(&Blob((0..64).collect())).expect("encode");
        let hash = store.put(&bytes).expect("put");
        // Wait until the object is old enough to be trusted by its metadata.
        std::thread::sleep(std::time::Duration::from_millis(2100));
        assert_eq!(
            store.object_state_cached(&hash).expect("state"),
            ObjectState::Present
        );
        assert!(store.save_stat_cache());
        let reopened = Store::open(dir.path()).expect("open");
        assert_eq!(
            reopened.object_state_cached(&hash).expect("state"),
            ObjectState::Present
        );

        let mut damaged = bytes.clone();
        damaged[30] ^= 4;
        fs::write(store.object_path(&hash), &damaged).expect("write");
        assert!(matches!(
            reopened.object_state_cached(&hash).expect("state"),
            ObjectState::Damaged { .. }
        ));
        fs::remove_file(store.object_path(&hash)).expect("remove");
        assert_eq!(
            reopened.object_state_cached(&hash).expect("state"),
            ObjectState::Missing
        );
    }

    #[test]
    fn task_stores_write_through_their_own_directory_which_the_lock_leaves_alone() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        let task = store.for_task("4242_3").expect("task store");
        let hash = task
            .put(&encode(&Blob(vec![7])).expect("encode"))
            .expect("put");
        assert_eq!(
            store.get(&hash).expect("visible to all"),
            task.get(&hash).expect("get")
        );
        // A task killed mid-write leaves its temp file in its directory...
        fs::write(dir.path().join("tmp/tasks/4242_3/99-0"), "half").expect("write");
        fs::write(dir.path().join("tmp/77-0"), "half").expect("write");
        drop(store.lock(|| {}).expect("lock"));
        // ...which the lock holder does not touch (the task may still be running)...
        assert!(dir.path().join("tmp/tasks/4242_3/99-0").exists());
        assert!(!dir.path().join("tmp/77-0").exists());
        assert_eq!(store.task_dirs().expect("list"), vec!["4242_3".to_string()]);
        // ...until the task is known to be gone.
        store.remove_task_dir("4242_3").expect("remove");
        assert!(store.task_dirs().expect("list").is_empty());
        assert!(store.verify().expect("verify").problems.is_empty());
        for bad in ["", "../x", ".hidden", "a/b"] {
            assert!(store.for_task(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn open_existing_refuses_a_path_that_is_not_a_store_and_creates_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let missing = dir.path().join("not-mounted-here");
        let err = Store::open_existing(&missing).expect_err("refused");
        assert!(matches!(err, Error::NotShared { .. }), "{err}");
        assert!(
            err.to_string().contains("shared by the submit host"),
            "{err}"
        );
        assert!(!missing.exists());
        Store::open(&missing).expect("create");
        Store::open_existing(&missing).expect("now it is one");
    }

    #[test]
    fn lock_clears_tmp_debris() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        fs::write(dir.path().join("tmp/123-0"), "half").expect("write");
        let _lock = store.lock(|| {}).expect("lock");
        assert_eq!(
            fs::read_dir(dir.path().join("tmp")).expect("read").count(),
            0
        );
    }
}
