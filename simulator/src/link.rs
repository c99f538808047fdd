//! `--link PATH`: a symbolic link to the pseudo-terminal at a fixed path, for hosts configured with
//! one (shared by `sonar-sim` and `sonar-firmware-sim`).

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use tracing::warn;

use crate::serve::Pty;

/// Why the link could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SymlinkError {
    #[error("{} exists and is not a symbolic link", .0.display())]
    NotALink(PathBuf),
    #[error("removing the old link {}: {source}", .link.display())]
    RemoveOld { link: PathBuf, source: io::Error },
    #[error("linking {} to {}: {source}", .link.display(), .target.display())]
    Create {
        link: PathBuf,
        target: PathBuf,
        source: io::Error,
    },
}

/// Why a head's pseudo-terminal could not be opened and announced.
#[derive(Debug, thiserror::Error)]
pub enum AnnounceError {
    #[error("opening a pseudo-terminal: {0}")]
    Pty(io::Error),
    #[error(transparent)]
    Link(#[from] SymlinkError),
    #[error("writing the PTY line to standard output: {0}")]
    Stdout(io::Error),
}

/// Opens the head's pseudo-terminal as both simulators present it: the `--link` exists before
/// anyone learns the path, which is then the first line on standard output, `PTY <path>`.
pub fn open_announced(link: Option<&Path>) -> Result<(Pty, Option<Symlink>), AnnounceError> {
    let pty = Pty::open().map_err(AnnounceError::Pty)?;
    let link = link
        .map(|link| Symlink::create(link, pty.path()))
        .transpose()?;
    let mut stdout = io::stdout().lock();
    writeln!(stdout, "PTY {}", pty.path().display())
        .and_then(|()| stdout.flush())
        .map_err(AnnounceError::Stdout)?;
    Ok((pty, link))
}

/// A symbolic link to the pseudo-terminal, removed when dropped.
#[derive(Debug)]
pub struct Symlink {
    link: PathBuf,
    target: PathBuf,
}

impl Symlink {
    /// Links `link` to `target`, replacing a stale link from an earlier run (never another file).
    pub fn create(link: &Path, target: &Path) -> Result<Self, SymlinkError> {
        if let Ok(meta) = std::fs::symlink_metadata(link) {
            if !meta.file_type().is_symlink() {
                return Err(SymlinkError::NotALink(link.to_owned()));
            }
            // A stale link from an earlier run that did not exit cleanly.
            std::fs::remove_file(link).map_err(|source| SymlinkError::RemoveOld {
                link: link.to_owned(),
                source,
            })?;
        }
        std::os::unix::fs::symlink(target, link).map_err(|source| SymlinkError::Create {
            link: link.to_owned(),
            target: target.to_owned(),
            source,
        })?;
        Ok(Self {
            link: link.to_owned(),
            target: target.to_owned(),
        })
    }
}

impl Drop for Symlink {
    fn drop(&mut self) {
        // Only our own link: another simulator may have taken the path over since.
        if std::fs::read_link(&self.link).is_ok_and(|t| t == self.target)
            && let Err(e) = std::fs::remove_file(&self.link)
        {
            warn!("cannot remove {}: {e}", self.link.display());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn links_replace_stale_links_never_files_and_go_away_when_dropped() {
        let dir = std::env::temp_dir().join(format!("sonar-link-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let link = dir.join("tty");
        std::os::unix::fs::symlink("/nonexistent/old", &link).unwrap();
        let made = Symlink::create(&link, Path::new("/dev/null")).unwrap();
        assert_eq!(std::fs::read_link(&link).unwrap(), Path::new("/dev/null"));
        drop(made);
        assert!(std::fs::symlink_metadata(&link).is_err(), "removed");

        let file = dir.join("file");
        std::fs::write(&file, b"").unwrap();
        assert!(matches!(
            Symlink::create(&file, Path::new("/dev/null")),
            Err(SymlinkError::NotALink(_))
        ));
        // A link another process took over is left alone.
        let made = Symlink::create(&link, Path::new("/dev/null")).unwrap();
        std::fs::remove_file(&link).unwrap();
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        drop(made);
        assert_eq!(std::fs::read_link(&link).unwrap(), Path::new("/dev/zero"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
