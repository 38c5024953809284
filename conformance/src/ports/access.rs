//! Whether this user may open a port (its owner, group and mode against this process's
//! user and groups), and the UUCP lock file another program may hold on it.

use std::path::{Path, PathBuf};

use serde::Serialize;

/// Whether this user may open a port for reading and writing.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Access {
    /// Yes, no, or unknown (`None`: not found out on this system).
    pub may_open: Option<bool>,
    /// Why: by which of the owner, group or others' rights, or what is missing.
    pub why: String,
    /// The command that gives the right, when it is missing.
    pub fix: Option<String>,
}

impl Access {
    /// Not found out (a system this check does not know).
    pub fn unknown() -> Access {
        Access {
            may_open: None,
            why: "not checked on this system".into(),
            fix: None,
        }
    }
}

/// A `LCK..<tty>` file: some program said it has the port open.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Lock {
    /// The lock file.
    pub file: PathBuf,
    /// The process id written in it, when it holds one.
    pub pid: Option<i32>,
    /// Whether that process still runs (a dead one left a stale lock).
    pub alive: Option<bool>,
    /// The process's command name, from `/proc/<pid>/comm`, where there is one.
    pub command: Option<String>,
}

/// Whether this process may open `path` for reading and writing.
#[cfg(unix)]
pub fn access(path: &Path) -> Access {
    use nix::unistd::{getegid, geteuid, getgroups, Gid, Group, Uid, User};
    use std::os::unix::fs::MetadataExt;

    let meta = match std::fs::metadata(path) {
        Ok(m) => m,
        Err(e) => {
            return Access {
                may_open: Some(false),
                why: format!("cannot look at {}: {e}", path.display()),
                fix: None,
            }
        }
    };
    let (mode, uid, gid) = (meta.mode(), meta.uid(), meta.gid());
    let group_name = Group::from_gid(Gid::from_raw(gid))
        .ok()
        .flatten()
        .map(|g| g.name)
        .unwrap_or_else(|| gid.to_string());
    let yes = |why: String| Access {
        may_open: Some(true),
        why,
        fix: None,
    };
    let me = geteuid();
    if me.is_root() {
        return yes("you are root".into());
    }
    let rw = |shift: u32| (mode >> shift) & 0o6 == 0o6;
    if me == Uid::from_raw(uid) && rw(6) {
        return yes("you own it".into());
    }
    let my_groups = getgroups().unwrap_or_default();
    let in_group = getegid() == Gid::from_raw(gid) || my_groups.contains(&Gid::from_raw(gid));
    if in_group && rw(3) {
        return yes(format!("through group {group_name}, which you are in"));
    }
    if rw(0) {
        return yes("everyone may".into());
    }
    let user = User::from_uid(me)
        .ok()
        .flatten()
        .map(|u| u.name)
        .unwrap_or_else(|| me.to_string());
    // Added to the group but not yet logged in again: the group is in /etc/group and not
    // in this session's groups, which a new login (or newgrp) brings.
    let listed = Group::from_gid(Gid::from_raw(gid))
        .ok()
        .flatten()
        .is_some_and(|g| g.mem.contains(&user));
    if !in_group && rw(3) {
        return Access {
            may_open: Some(false),
            why: if listed {
                format!("{user} is in group {group_name} since the last login, not in this session")
            } else {
                format!(
                    "it is {:o} owned by group {group_name}, and {user} is not in that group",
                    mode & 0o777
                )
            },
            fix: Some(if listed {
                format!("log out and in again (or: newgrp {group_name})")
            } else {
                format!("sudo usermod -aG {group_name} {user}, then log out and in again")
            }),
        };
    }
    Access {
        may_open: Some(false),
        why: format!(
            "its mode {:o} gives {user} no read and write right",
            mode & 0o777
        ),
        fix: None,
    }
}

/// Not found out outside Unix.
#[cfg(not(unix))]
pub fn access(_path: &Path) -> Access {
    Access::unknown()
}

/// The lock file for tty `name` in the first of `dirs` that has one.
pub fn lock(dirs: &[PathBuf], name: &str) -> Option<Lock> {
    let file = dirs
        .iter()
        .map(|d| d.join(format!("LCK..{name}")))
        .find(|f| f.is_file())?;
    // Two formats are in use: the pid as ten ASCII digits and a newline (HDB, what
    // lockdev and minicom write), or as a binary 4-byte integer (older programs). Only
    // the first bytes are read: a lock file is a few bytes, whatever lies there.
    let mut bytes = Vec::new();
    if let Ok(f) = std::fs::File::open(&file) {
        use std::io::Read;
        let _ = f.take(64).read_to_end(&mut bytes);
    }
    let pid = std::str::from_utf8(&bytes)
        .ok()
        .and_then(|t| t.trim().parse::<i32>().ok())
        .or_else(|| {
            <[u8; 4]>::try_from(bytes.as_slice())
                .ok()
                .map(i32::from_ne_bytes)
        })
        .filter(|p| *p > 0);
    let alive = pid.and_then(alive);
    let command = pid
        .filter(|_| alive == Some(true))
        .and_then(|p| std::fs::read_to_string(format!("/proc/{p}/comm")).ok())
        .map(|c| c.trim().to_string());
    Some(Lock {
        file,
        pid,
        alive,
        command,
    })
}

/// Whether process `pid` runs (signal 0 asks without sending anything).
#[cfg(unix)]
fn alive(pid: i32) -> Option<bool> {
    use nix::errno::Errno;
    match nix::sys::signal::kill(nix::unistd::Pid::from_raw(pid), None) {
        Ok(()) | Err(Errno::EPERM) => Some(true),
        Err(Errno::ESRCH) => Some(false),
        Err(_) => None,
    }
}

#[cfg(not(unix))]
fn alive(_pid: i32) -> Option<bool> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("ports-lock-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_lock_names_its_pid_in_either_format_and_whether_it_runs() {
        let d = dir("formats");
        let me = std::process::id() as i32;
        std::fs::write(d.join("LCK..ttyUSB0"), format!("{me:>10}\n")).unwrap();
        let l = lock(std::slice::from_ref(&d), "ttyUSB0").unwrap();
        assert_eq!((l.pid, l.alive), (Some(me), Some(true)));
        std::fs::write(d.join("LCK..ttyUSB1"), me.to_ne_bytes()).unwrap();
        assert_eq!(
            lock(std::slice::from_ref(&d), "ttyUSB1").unwrap().pid,
            Some(me)
        );
        // Garbage and a huge file: no pid, no panic, only the first bytes read.
        std::fs::write(d.join("LCK..ttyUSB2"), vec![0xFFu8; 1 << 20]).unwrap();
        let l = lock(std::slice::from_ref(&d), "ttyUSB2").unwrap();
        assert_eq!((l.pid, l.alive), (None, None));
        assert!(lock(std::slice::from_ref(&d), "ttyUSB3").is_none());
        let _ = std::fs::remove_dir_all(&d);
    }
}
