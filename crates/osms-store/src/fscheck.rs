//! Whether a store's filesystem gives what cluster builds rely on: a rename over an existing
//! file that replaces it in one step (every write), and advisory locks that exclude a second
//! holder (the driver's store lock). Checked by the Slurm driver before it submits anything.

use std::fs::{self, OpenOptions};
use std::path::Path;

use serde::Serialize;

use crate::store::{Store, StoreLock};
use crate::{Error, Result};

/// What kind of filesystem a store is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FsClass {
    /// A filesystem that compute nodes can mount (NFS, Lustre, GPFS, BeeGFS, CephFS).
    Network,
    /// A disk of this host (ext4, xfs, btrfs, tmpfs, ...): fine for a single-node cluster only.
    Local,
    /// Known not to give atomic renames over existing files or working locks.
    Unsafe,
    /// Anything else, e.g. a FUSE filesystem, whose guarantees depend on the implementation.
    Unknown,
}

#[derive(Debug, Clone, Serialize)]
pub struct FsCheck {
    /// The filesystem's name (from its `statfs` magic number).
    pub name: String,
    pub class: FsClass,
}

/// (magic, name, class) of the filesystems osms knows, from `statfs(2)`.
const KNOWN: &[(i64, &str, FsClass)] = &[
    (0x6969, "nfs", FsClass::Network),
    (0x0BD0_0BD0, "lustre", FsClass::Network),
    (0x4750_4653, "gpfs", FsClass::Network),
    (0x1983_0326, "beegfs", FsClass::Network),
    (0x00C3_6400, "ceph", FsClass::Network),
    (0xFF53_4D42, "cifs", FsClass::Unsafe),
    (0xFE53_4D42, "smb2", FsClass::Unsafe),
    (0x517B, "smb", FsClass::Unsafe),
    (0x6573_5546, "fuse", FsClass::Unknown),
    (0xEF53, "ext4", FsClass::Local),
    (0x5846_5342, "xfs", FsClass::Local),
    (0x9123_683E, "btrfs", FsClass::Local),
    (0x0102_1994, "tmpfs", FsClass::Local),
    (0x794C_7630, "overlayfs", FsClass::Local),
    (0x2FC1_2FC1, "zfs", FsClass::Local),
];

/// Classifies a `statfs` magic number.
pub fn classify(magic: i64) -> FsCheck {
    match KNOWN.iter().find(|(m, _, _)| *m == magic) {
        Some((_, name, class)) => FsCheck {
            name: (*name).to_string(),
            class: *class,
        },
        None => FsCheck {
            name: format!("unknown filesystem 0x{magic:x}"),
            class: FsClass::Unknown,
        },
    }
}

/// The workspace denies `unsafe_code`; `statfs(2)` has no safe wrapper in std.
#[allow(unsafe_code)]
fn statfs_magic(path: &Path) -> Result<i64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).map_err(|_| Error::Foreign {
        reason: format!("{} contains a NUL byte", path.display()),
    })?;
    let mut buf = std::mem::MaybeUninit::<libc::statfs>::uninit();
    // SAFETY: `c` is a NUL-terminated path and `buf` is large enough for one `statfs`, which
    // the call fills entirely when it returns 0.
    let rc = unsafe { libc::statfs(c.as_ptr(), buf.as_mut_ptr()) };
    if rc != 0 {
        return Err(Error::io(path, std::io::Error::last_os_error()));
    }
    // SAFETY: initialised by the successful call above.
    let st = unsafe { buf.assume_init() };
    #[allow(clippy::unnecessary_cast)]
    Ok((st.f_type as i64) & 0xFFFF_FFFF)
}

impl Store {
    /// Checks that this store can take writes from cluster tasks: refuses filesystems known to
    /// lack atomic renames or locks (and unknown ones unless `trust` is set), then tries both
    /// guarantees for real. `_lock` proves the caller holds the store lock, which the lock test
    /// needs.
    pub fn check_for_cluster(&self, _lock: &StoreLock, trust: bool) -> Result<FsCheck> {
        let check = classify(statfs_magic(self.root())?);
        let refuse = |why: String| Error::UnsafeFilesystem {
            root: self.root().to_path_buf(),
            name: check.name.clone(),
            why,
        };
        match check.class {
            FsClass::Unsafe => {
                return Err(refuse(
                    "SMB/CIFS does not replace an existing file atomically on rename, and its \
                     locks are not POSIX locks"
                        .into(),
                ));
            }
            FsClass::Unknown if !trust => {
                return Err(refuse(
                    "osms does not know whether it renames atomically and honours locks; if it \
                     does, set `trust_filesystem = true` under [executor.slurm]"
                        .into(),
                ));
            }
            _ => {}
        }
        let tmp = self.root().join("tmp");
        let (a, b) = (tmp.join(".fscheck-a"), tmp.join(".fscheck-b"));
        let renamed = (|| {
            fs::write(&a, b"old")?;
            fs::write(&b, b"new")?;
            fs::rename(&b, &a)?;
            fs::read(&a)
        })();
        let _ = fs::remove_file(&a);
        let _ = fs::remove_file(&b);
        match renamed {
            Ok(bytes) if bytes == b"new" => {}
            Ok(_) => {
                return Err(refuse(
                    "a rename over an existing file kept the old file".into(),
                ));
            }
            Err(e) => {
                return Err(refuse(format!(
                    "a rename over an existing file failed: {e}"
                )));
            }
        }
        let path = self.root().join("lock");
        let second = OpenOptions::new()
            .write(true)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        match second.try_lock() {
            Err(fs::TryLockError::WouldBlock) => Ok(check),
            Ok(()) => Err(refuse(
                "a second open of the lock file took the lock the driver holds: locks are not \
                 enforced (an NFS mount with `nolock` or `local_lock`?)"
                    .into(),
            )),
            Err(fs::TryLockError::Error(e)) => Err(refuse(format!(
                "locking failed: {e} (on Lustre, mount with `-o flock`)"
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn magic_numbers_are_classified() {
        assert_eq!(classify(0x6969).class, FsClass::Network);
        assert_eq!(classify(0x0BD0_0BD0).name, "lustre");
        assert_eq!(classify(0xFF53_4D42).class, FsClass::Unsafe);
        assert_eq!(classify(0xEF53).class, FsClass::Local);
        let other = classify(0x1234);
        assert_eq!(other.class, FsClass::Unknown);
        assert!(other.name.contains("0x1234"), "{}", other.name);
    }

    #[test]
    fn this_machine_s_store_passes_the_check_only_under_the_lock() {
        let dir = tempfile::tempdir().expect("tempdir");
        let store = Store::open(dir.path()).expect("open");
        let lock = store.lock(|| {}).expect("lock");
        let check = store
            .check_for_cluster(&lock, true)
            .expect("local disks rename and lock");
        assert_ne!(check.class, FsClass::Unsafe);
        assert!(
            fs::read_dir(dir.path().join("tmp"))
                .expect("tmp")
                .next()
                .is_none(),
            "the probe cleans up"
        );
    }
}
