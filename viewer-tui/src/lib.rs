//! `sonar-viewer`: the terminal viewer of the sonar pipeline (ratatui + crossterm), usable over SSH.
//!
//! It shows the fusion engine's probability map as a heatmap, the basic method's radar display, or
//! both side by side, with a status panel on the driver and the fusion engine; its keys send scan
//! and fusion commands over iceoryx2, so it owns no hardware and can be started, stopped and
//! restarted at any time, before or after the other processes.
//!
//! Design, one concern per module:
//! - [`heatmap`]: pure pixel work. Which grid cells each pixel covers (zoom, pan), the max-pool that
//!   turns a block of cells into one pixel without ever hiding an occupied cell, and the colour
//!   code (blue free → pale even odds → red occupied, dark grey never observed) for truecolor or
//!   the 256-colour palette, in 16 colours or as shade glyphs without colour; which part of the
//!   grid has been seen (the default framing); and which pixels show the walls, corners and posts
//!   of `sonar/features` over the map.
//! - [`app`]: the state and the key handling, free of I/O: snapshots come in as copies, key presses
//!   and mouse events come in as crossterm events, and what must happen outside comes out as an
//!   [`app::Action`].
//! - [`ui`]: rendering of that state into a ratatui buffer, the map drawn two pixels per cell with
//!   half-block glyphs chosen so that even colourless text shows the walls; a compact layout for
//!   small terminals; scale bar and legends in the views' borders.
//! - [`source`]: the iceoryx2 ports: opened lazily and retried, drained to the newest sample once
//!   per frame and copied out at once, publisher liveness, commands.
//! - [`export`]: the map as a PNG.
//!
//! The binary (`main.rs`) owns the terminal: raw mode and the alternate screen, restored on exit,
//! on panic and on SIGTERM/SIGINT/SIGHUP; logs go to a file, never to the screen it draws on.

pub mod app;
pub mod export;
pub mod heatmap;
pub mod source;
pub mod ui;
