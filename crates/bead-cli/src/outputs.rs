//! The files a command writes, checked before anything runs: no two outputs may be the same
//! file (one would silently overwrite the other), and no output may be an input (the scene
//! file, the trace being plotted). Paths are compared canonicalized where they exist (so
//! `out.csv`, `./out.csv` and a symbolic link to it are the same file), a dangling symbolic
//! link as the file it would create, else through their canonicalized directory, else
//! lexically; existing files also by device and inode (hard links).

use std::path::{Component, Path, PathBuf};

use crate::commands::Usage;

/// One file, who names it, and its identity for comparison.
struct Entry {
    /// `--summary out.json`, or `--trace t.csv (writing t.implicit.csv)`.
    who: String,
    identity: Identity,
    input: bool,
}

/// Where a path leads: the file's resolved path, and its device and inode when it exists
/// (Unix), which two hard links share.
#[derive(Debug)]
struct Identity {
    path: PathBuf,
    inode: Option<(u64, u64)>,
}

impl Identity {
    fn same(&self, other: &Identity) -> bool {
        self.path == other.path || (self.inode.is_some() && self.inode == other.inode)
    }
}

/// The inputs and outputs of one command.
#[derive(Default)]
pub struct Files {
    entries: Vec<Entry>,
}

impl Files {
    pub fn new() -> Self {
        Files::default()
    }

    /// A file the command reads (`what`: e.g. `the scene file`), which no output may be.
    pub fn input(&mut self, what: &str, path: &Path) -> &mut Self {
        self.entries.push(Entry {
            who: format!("{what} {}", path.display()),
            identity: identity(path),
            input: true,
        });
        self
    }

    /// A file that `flag` names directly (`--summary out.json`).
    pub fn output(&mut self, flag: &str, path: &Path) -> &mut Self {
        self.entries.push(Entry {
            who: format!("{flag} {}", path.display()),
            identity: identity(path),
            input: false,
        });
        self
    }

    /// A file that `flag GIVEN` makes the command write at `path` (`--trace t.csv` writes
    /// `t.implicit.csv`), for `run` when one flag writes several files by run.
    pub fn derived(
        &mut self,
        flag: &str,
        given: &Path,
        path: &Path,
        run: Option<&str>,
    ) -> &mut Self {
        let run = run.map(|r| format!(" for {r}")).unwrap_or_default();
        self.entries.push(Entry {
            who: format!(
                "{flag} {} (writing {}{run})",
                given.display(),
                path.display()
            ),
            identity: identity(path),
            input: false,
        });
        self
    }

    /// A usage error naming the first two entries that are the same file.
    pub fn check(&self) -> Result<(), Usage> {
        for (j, later) in self.entries.iter().enumerate() {
            for earlier in &self.entries[..j] {
                if !earlier.identity.same(&later.identity) {
                    continue;
                }
                return Err(Usage(match (earlier.input, later.input) {
                    (true, true) => continue,
                    (true, false) => format!("{} would overwrite {}", later.who, earlier.who),
                    (false, true) => format!("{} would overwrite {}", earlier.who, later.who),
                    (false, false) => format!(
                        "{} and {} are the same file; give each output its own path",
                        earlier.who, later.who
                    ),
                }));
            }
        }
        Ok(())
    }
}

/// Where `path` leads ([`resolved`]), and the device and inode of the file there.
fn identity(path: &Path) -> Identity {
    #[cfg(unix)]
    let inode = {
        use std::os::unix::fs::MetadataExt;
        std::fs::metadata(path).ok().map(|m| (m.dev(), m.ino()))
    };
    #[cfg(not(unix))]
    let inode = None;
    Identity {
        path: resolved(path, 40),
        inode,
    }
}

/// `path` canonicalized if it exists; a symbolic link that leads nowhere (yet), as its
/// target (relative to the link's directory; at most `links` links deep); else its
/// canonicalized directory joined with its name; else made absolute and normalized
/// lexically.
fn resolved(path: &Path, links: u32) -> PathBuf {
    if let Ok(canonical) = std::fs::canonicalize(path) {
        return canonical;
    }
    if links > 0 {
        if let Ok(target) = std::fs::read_link(path) {
            let base = path.parent().unwrap_or(Path::new(""));
            return resolved(&base.join(target), links - 1);
        }
    }
    let absolute = match std::env::current_dir() {
        Ok(dir) => dir.join(path),
        Err(_) => path.to_path_buf(),
    };
    let absolute = lexical(&absolute);
    if let (Some(parent), Some(name)) = (absolute.parent(), absolute.file_name()) {
        if let Ok(parent) = std::fs::canonicalize(parent) {
            return parent.join(name);
        }
    }
    absolute
}

/// `path` without `.` components, `..` applied to the components before it.
fn lexical(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for component in path.components() {
        match component {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push(component);
                }
            }
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lexical_drops_dots_and_applies_parents() {
        assert_eq!(
            lexical(Path::new("/a/./b/../c.csv")),
            PathBuf::from("/a/c.csv")
        );
    }

    #[test]
    fn the_same_file_named_twice_is_refused_with_both_flags() {
        let mut files = Files::new();
        files
            .output("--trace", Path::new("no-such-dir/out.csv"))
            .output("--summary", Path::new("no-such-dir/./out.csv"));
        assert_eq!(
            files.check().unwrap_err().0,
            "--trace no-such-dir/out.csv and --summary no-such-dir/./out.csv are the same file; give each output its own path"
        );
        let mut files = Files::new();
        files
            .input("the scene file", Path::new("s.toml"))
            .output("--summary", Path::new("s.toml"));
        assert_eq!(
            files.check().unwrap_err().0,
            "--summary s.toml would overwrite the scene file s.toml"
        );
        let mut files = Files::new();
        files
            .output("--trace", Path::new("a.csv"))
            .output("--summary", Path::new("b.csv"));
        assert!(files.check().is_ok());
    }

    /// A hard link to a file is that file, and so is a symbolic link to a file that does
    /// not exist yet (writing through it creates the file); a link chain that loops is
    /// compared as itself.
    #[cfg(unix)]
    #[test]
    fn hard_links_and_dangling_symbolic_links_are_the_files_they_lead_to() {
        let dir = std::env::temp_dir().join(format!("bead-outputs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let scene = dir.join("s.toml");
        std::fs::write(&scene, "title = \"x\"\n").unwrap();
        std::fs::hard_link(&scene, dir.join("hard.json")).unwrap();
        std::os::unix::fs::symlink("later.csv", dir.join("dangling.csv")).unwrap();
        std::os::unix::fs::symlink("loop-b", dir.join("loop-a")).unwrap();
        std::os::unix::fs::symlink("loop-a", dir.join("loop-b")).unwrap();
        let mut files = Files::new();
        files
            .input("the scene file", &scene)
            .output("--summary", &dir.join("hard.json"));
        assert!(files
            .check()
            .unwrap_err()
            .0
            .contains("would overwrite the scene file"));
        let mut files = Files::new();
        files
            .output("--trace", &dir.join("dangling.csv"))
            .output("--summary", &dir.join("later.csv"));
        assert!(files.check().unwrap_err().0.contains("are the same file"));
        let mut files = Files::new();
        files
            .output("--trace", &dir.join("loop-a"))
            .output("--summary", &dir.join("other.csv"));
        assert!(files.check().is_ok());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
