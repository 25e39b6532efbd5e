//! The files a command writes, checked before anything runs: no two outputs may be the same
//! file (one would silently overwrite the other), and no output may be an input (the scene
//! file, the trace being plotted). Paths are compared canonicalized where they exist (so
//! `out.csv`, `./out.csv` and a symbolic link to it are the same file), else through their
//! canonicalized directory, else lexically.

use std::path::{Component, Path, PathBuf};

use crate::commands::Usage;

/// One file, who names it, and its identity for comparison.
struct Entry {
    /// `--summary out.json`, or `--trace t.csv (writing t.implicit.csv)`.
    who: String,
    identity: PathBuf,
    input: bool,
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
                if earlier.identity != later.identity {
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

/// `path` canonicalized if it exists; else its canonicalized directory joined with its name;
/// else made absolute and normalized lexically.
fn identity(path: &Path) -> PathBuf {
    if let Ok(canonical) = std::fs::canonicalize(path) {
        return canonical;
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
}
