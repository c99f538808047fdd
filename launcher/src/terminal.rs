//! The terminal the launcher shares with the viewer, put back as it was when the viewer could not
//! do it itself (killed by a signal: raw mode, the alternate screen and a hidden cursor stay).

use std::io::{IsTerminal, Write};

use nix::sys::termios::{SetArg, Termios, tcgetattr, tcsetattr};
use tracing::warn;

/// Leave the alternate screen, show the cursor: what the viewer's own clean-up writes.
const RESTORE_SCREEN: &[u8] = b"\x1b[?1049l\x1b[?25h";

/// The terminal's settings before the viewer first ran; `None` if standard input is no terminal.
#[derive(Debug)]
pub struct Terminal {
    settings: Option<Termios>,
}

impl Terminal {
    /// Remembers the settings of the terminal on standard input (call it before the viewer starts).
    pub fn capture() -> Self {
        let stdin = std::io::stdin();
        let settings = if stdin.is_terminal() {
            tcgetattr(&stdin)
                .inspect_err(|e| warn!("cannot read the terminal's settings: {e}"))
                .ok()
        } else {
            None
        };
        Self { settings }
    }

    /// Back to the captured settings (raw mode off) and to the normal screen with a cursor, so the
    /// next viewer starts from a clean terminal and an error printed now is readable.
    pub fn restore(&self) {
        let Some(settings) = &self.settings else {
            return;
        };
        if let Err(e) = tcsetattr(std::io::stdin(), SetArg::TCSANOW, settings) {
            warn!("cannot restore the terminal's settings: {e}");
        }
        let mut out = std::io::stdout();
        if let Err(e) = out.write_all(RESTORE_SCREEN).and_then(|()| out.flush()) {
            warn!("cannot restore the terminal's screen: {e}");
        }
    }
}
