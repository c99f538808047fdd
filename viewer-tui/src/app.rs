//! The viewer's state and what keys do to it.
//!
//! No I/O here: the IPC layer feeds copies of snapshots in through the `on_*` methods, key presses
//! come in through [`App::on_key`], and whatever must reach the outside world (commands, saving a
//! PNG, quitting) comes out as an [`Action`]. Times are passed in, never read, so the tests control
//! the clock.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use crossterm::event::{
    KeyCode, KeyEvent, KeyEventKind, KeyModifiers, MouseButton, MouseEvent, MouseEventKind,
};
use sonar_common::ipc::{
    DriverStatus, FeatureRecord, FeaturesHeader, FusionCommand, FusionCommandKind, FusionStatus,
    GridHeader, LAYOUT_VERSION, LocalizedPose, MAX_FEATURES, RADAR_MAX_BINS, Radar, Reading,
    ScanCommand, ScanCommandKind, ScanMode, SlamCorrection, preset_code, slam_state,
};
use sonar_common::sensor::SensorConfig;

use crate::heatmap::{CellBox, MAX_PIXELS_PER_CELL, Palette, Viewport, seen_box};

/// How long a producer may go without a sample or a live publisher before it counts as gone. The
/// driver publishes its status every second and publishers are checked every second, so three
/// seconds rides out a busy moment without letting a crash go unnoticed for long.
pub const PEER_TIMEOUT: Duration = Duration::from_secs(3);
/// Readings listed in the status panel.
pub const LAST_READINGS: usize = 3;
/// One key press turns or widens the local-scan segment by one reading's span.
pub const SEGMENT_STEP_DEG: f32 = 6.0;
/// The narrowest local scan the selection allows: two readings.
pub const SEGMENT_MIN_WIDTH_DEG: f32 = 12.0;
/// Cursor steps per key press with Shift.
const FAST_STEPS: i64 = 8;
/// Positions the robot's trail keeps: a room tour's worth at one per cell moved.
pub const TRAIL_LEN: usize = 500;
/// Once the robot is this far from where the viewer first saw it, the map follows it (unless `t`
/// was pressed): a fixed head never moves, so it keeps today's view, a robot gets followed.
pub const AUTO_FOLLOW_M: f32 = 0.5;
/// The view framing what has been seen is at least this wide and tall, metres: a few observed
/// cells around a fresh start are not blown up to fill the screen.
pub const MIN_FRAME_M: f32 = 2.0;

/// What the main area shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// The probability map.
    Map,
    /// The basic method's radar display.
    Radar,
    /// Both side by side.
    Split,
}

impl View {
    fn next(self) -> Self {
        match self {
            View::Map => View::Radar,
            View::Radar => View::Split,
            View::Split => View::Map,
        }
    }
}

/// Whether a producer process is there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Liveness {
    /// Never seen since the viewer started.
    Waiting,
    Alive,
    /// Seen before, silent for this long.
    Gone(Duration),
}

impl Liveness {
    /// As the status panel words it: "gone for N s" in whole seconds.
    fn as_shown(self) -> Self {
        match self {
            Liveness::Gone(d) => Liveness::Gone(Duration::from_secs(d.as_secs())),
            other => other,
        }
    }
}

/// When a producer was last seen: a sample from it, or its publisher with a live node.
#[derive(Debug, Default, Clone, Copy)]
pub struct Peer {
    last_seen: Option<Instant>,
}

impl Peer {
    pub fn seen(&mut self, now: Instant) {
        self.last_seen = Some(self.last_seen.map_or(now, |t| t.max(now)));
    }

    pub fn liveness(&self, now: Instant) -> Liveness {
        match self.last_seen {
            None => Liveness::Waiting,
            Some(t) => {
                let silent = now.saturating_duration_since(t);
                if silent <= PEER_TIMEOUT {
                    Liveness::Alive
                } else {
                    Liveness::Gone(silent)
                }
            }
        }
    }
}

/// A private copy of one `sonar/grid` snapshot (so no shared-memory sample is held across frames).
#[derive(Debug, Clone, Default)]
pub struct GridSnapshot {
    pub header: GridHeader,
    /// `width × height` cells, row 0 at the lowest y, as published.
    pub cells: Vec<u8>,
    /// The smallest box holding every observed cell; `None` before any was observed.
    pub seen: Option<CellBox>,
}

impl GridSnapshot {
    pub fn width(&self) -> u32 {
        self.header.width
    }

    pub fn height(&self) -> u32 {
        self.header.height
    }

    pub fn cell(&self, x: u32, y: u32) -> Option<u8> {
        if x >= self.width() || y >= self.height() {
            return None;
        }
        self.cells
            .get(y as usize * self.width() as usize + x as usize)
            .copied()
    }

    /// World coordinates of the centre of cell (`x`, `y`), metres.
    pub fn cell_center_m(&self, x: u32, y: u32) -> (f32, f32) {
        let h = &self.header;
        (
            h.origin_x_m + (x as f32 + 0.5) * h.resolution_m,
            h.origin_y_m + (y as f32 + 0.5) * h.resolution_m,
        )
    }

    /// The cell containing the world point (`x_m`, `y_m`).
    pub fn cell_at_m(&self, x_m: f32, y_m: f32) -> Option<(u32, u32)> {
        let h = &self.header;
        let x = ((x_m - h.origin_x_m) / h.resolution_m).floor();
        let y = ((y_m - h.origin_y_m) / h.resolution_m).floor();
        let inside = |v: f32, n: u32| v >= 0.0 && v < n as f32;
        (inside(x, h.width) && inside(y, h.height)).then_some((x as u32, y as u32))
    }

    /// The cell under the sensor at the last fused reading.
    pub fn sensor_cell(&self) -> Option<(u32, u32)> {
        self.cell_at_m(self.header.pose_x_m, self.header.pose_y_m)
    }

    /// The sensor's pose at the last fused reading, as the fusion placed it (corrected when it
    /// localises); `None` when shared memory brought a non-finite one.
    pub fn pose(&self) -> Option<Pose> {
        let h = &self.header;
        [h.pose_x_m, h.pose_y_m, h.pose_theta_rad]
            .iter()
            .all(|v| v.is_finite())
            .then_some(Pose {
                x_m: h.pose_x_m,
                y_m: h.pose_y_m,
                theta_rad: h.pose_theta_rad,
            })
    }

    /// What the map shows by default: the observed cells and the sensor, with a margin of a
    /// twentieth of the larger side (at least two cells), at least [`MIN_FRAME_M`] per side; the
    /// whole grid while nothing was observed.
    pub fn seen_frame(&self) -> CellBox {
        let (w, h) = (self.width(), self.height());
        let Some(seen) = self.seen else {
            return CellBox::whole(w, h);
        };
        let seen = match self.sensor_cell() {
            Some((x, y)) => seen.including(x, y),
            None => seen,
        };
        let margin = (seen.width().max(seen.height()) / 20.0).max(2.0);
        let min_side = f64::from(MIN_FRAME_M / self.header.resolution_m);
        seen.padded(margin, min_side, w, h)
    }

    /// Continuous grid coordinates (cells, y up) of the world point (`x_m`, `y_m`), as the
    /// viewport's centre takes them.
    pub fn grid_point(&self, x_m: f32, y_m: f32) -> (f64, f64) {
        let h = &self.header;
        (
            f64::from((x_m - h.origin_x_m) / h.resolution_m),
            f64::from((y_m - h.origin_y_m) / h.resolution_m),
        )
    }
}

/// A sensor pose in the world: position of the rotation axis, metres, and heading (the sensor's
/// 0°), radians counter-clockwise from the x axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub x_m: f32,
    pub y_m: f32,
    pub theta_rad: f32,
}

/// Where the robot has been: the last [`TRAIL_LEN`] positions that lie more than a cell apart, in
/// world metres (so a grid that is resized or moves its origin does not shift them).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trail {
    points: VecDeque<(f32, f32)>,
}

impl Trail {
    /// Appends (`x_m`, `y_m`) if it lies more than `min_step_m` from the last position kept, so a
    /// robot standing still (or a fixed head) adds nothing; beyond [`TRAIL_LEN`] the oldest goes.
    /// Non-finite positions are ignored. True when appended.
    pub fn push(&mut self, x_m: f32, y_m: f32, min_step_m: f32) -> bool {
        if !(x_m.is_finite() && y_m.is_finite()) {
            return false;
        }
        let moved = self
            .points
            .back()
            .is_none_or(|&(x, y)| (x_m - x).hypot(y_m - y) > min_step_m);
        if moved {
            if self.points.len() >= TRAIL_LEN {
                self.points.pop_front();
            }
            self.points.push_back((x_m, y_m));
        }
        moved
    }

    pub fn clear(&mut self) {
        self.points.clear();
    }

    /// Oldest first.
    pub fn points(&self) -> impl Iterator<Item = (f32, f32)> + '_ {
        self.points.iter().copied()
    }
}

/// Why a grid snapshot cannot be shown; `Ok` when header and payload agree.
pub fn check_grid(header: &GridHeader, payload_len: usize) -> Result<(), String> {
    if header.layout_version != LAYOUT_VERSION {
        return Err(format!(
            "grid layout version {} (this viewer reads {LAYOUT_VERSION})",
            header.layout_version
        ));
    }
    let cells = (header.width as usize).checked_mul(header.height as usize);
    if header.width == 0 || header.height == 0 || cells != Some(payload_len) {
        return Err(format!(
            "grid {}×{} arrived with {payload_len} cells",
            header.width, header.height
        ));
    }
    if !(header.resolution_m.is_finite() && header.resolution_m > 0.0) {
        return Err(format!("grid resolution {} m", header.resolution_m));
    }
    Ok(())
}

/// A private copy of one `sonar/features` snapshot.
#[derive(Debug, Clone, Default)]
pub struct FeaturesSnapshot {
    pub header: FeaturesHeader,
    /// `header.feature_count` records, as published.
    pub records: Vec<FeatureRecord>,
}

/// Why a features snapshot cannot be shown; `Ok` when header and payload agree.
pub fn check_features(header: &FeaturesHeader, payload_len: usize) -> Result<(), String> {
    if header.layout_version != LAYOUT_VERSION {
        return Err(format!(
            "features layout version {} (this viewer reads {LAYOUT_VERSION})",
            header.layout_version
        ));
    }
    let count = header.feature_count as usize;
    if count != payload_len || count > MAX_FEATURES {
        return Err(format!(
            "{count} features announced, {payload_len} arrived (at most {MAX_FEATURES})"
        ));
    }
    Ok(())
}

/// Why a radar snapshot cannot be shown.
pub fn check_radar(radar: &Radar) -> Result<(), String> {
    if radar.layout_version != LAYOUT_VERSION {
        return Err(format!(
            "radar layout version {} (this viewer reads {LAYOUT_VERSION})",
            radar.layout_version
        ));
    }
    if radar.bin_count as usize > RADAR_MAX_BINS
        || (radar.bin_count > 0 && !(radar.bin_width_deg.is_finite() && radar.bin_width_deg > 0.0))
    {
        return Err(format!(
            "radar with {} bins of {}°",
            radar.bin_count, radar.bin_width_deg
        ));
    }
    Ok(())
}

/// An angular segment, degrees, `from_deg < to_deg`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub from_deg: f32,
    pub to_deg: f32,
}

impl Segment {
    /// The segment of `half_width` either side of `center`, kept within `limits`.
    pub fn around(center: f32, half_width: f32, limits: Segment) -> Self {
        let width = (2.0 * half_width).min(limits.to_deg - limits.from_deg);
        let from = (center - width / 2.0).clamp(limits.from_deg, limits.to_deg - width);
        Self {
            from_deg: from,
            to_deg: from + width,
        }
    }

    fn center(self) -> f32 {
        (self.from_deg + self.to_deg) / 2.0
    }

    fn half_width(self) -> f32 {
        (self.to_deg - self.from_deg) / 2.0
    }

    /// Turned counter-clockwise by `delta` (clockwise if negative), same width, within `limits`.
    pub fn turned(self, delta: f32, limits: Segment) -> Self {
        Self::around(self.center() + delta, self.half_width(), limits)
    }

    /// Widened by `delta` on each side (narrowed if negative), never below the minimum width.
    pub fn widened(self, delta: f32, limits: Segment) -> Self {
        let half = (self.half_width() + delta).max(SEGMENT_MIN_WIDTH_DEG / 2.0);
        Self::around(self.center(), half, limits)
    }
}

/// Where the sweep is, 0 at the start of its pass and 1 at the end; `None` without a direction.
pub fn sweep_progress(angle_deg: f32, direction: i32, limits: Segment) -> Option<f32> {
    let span = limits.to_deg - limits.from_deg;
    if !(span > 0.0 && angle_deg.is_finite()) {
        return None;
    }
    let f = ((angle_deg - limits.from_deg) / span).clamp(0.0, 1.0);
    match direction.signum() {
        1 => Some(f),
        -1 => Some(1.0 - f),
        _ => None,
    }
}

/// Readings per second from the driver's `readings_published` counter.
#[derive(Debug, Default, Clone, Copy)]
pub struct RateMeter {
    reference: Option<(u64, u64)>,
    per_second: Option<f64>,
}

impl RateMeter {
    /// Rates are taken over at least a second, so the status published on every state change does
    /// not make them jump.
    const MIN_SPAN_NS: u64 = 1_000_000_000;

    pub fn update(&mut self, stamp_ns: u64, count: u64) {
        match self.reference {
            Some((t0, c0)) if count >= c0 && stamp_ns >= t0 => {
                let dt = stamp_ns - t0;
                if dt >= Self::MIN_SPAN_NS {
                    self.per_second = Some((count - c0) as f64 * 1e9 / dt as f64);
                    self.reference = Some((stamp_ns, count));
                }
            }
            // First status, or the driver restarted and its counter began again.
            _ => {
                self.reference = Some((stamp_ns, count));
                self.per_second = None;
            }
        }
    }

    pub fn per_second(&self) -> Option<f64> {
        self.per_second
    }
}

/// Names and codes of the fusion settings, as in `sonar_common::ipc`; shared with the map files.
/// "custom" (in `PRESETS`) is what the engine reports after a model or rule change; `p` never asks
/// for it.
pub use sonar_mapfiles::settings::{MODELS, PRESETS, RULES, setting_name};

/// The code after `current` among `choices`, wrapping around; the first when `current` is not one.
fn next_setting(choices: &[u32], current: u32) -> u32 {
    let next = choices
        .iter()
        .position(|&c| c == current)
        .map_or(0, |i| (i + 1) % choices.len());
    choices.get(next).copied().unwrap_or(current)
}

/// The key bindings, for the `?` overlay and `--help`.
pub const KEYS: &[(&str, &str)] = &[
    ("f", "full scan"),
    ("l", "local scan: pick a segment on the radar"),
    ("  ←/→  ↑/↓", "turn / widen it, Enter scans, Esc cancels"),
    ("x", "stop scanning"),
    (
        "R",
        "reset a head stopped on a hardware fault, once checked",
    ),
    ("C", "clear the map"),
    ("m  r  p", "next sensor model / rule / preset"),
    ("arrows", "move the cursor (Shift: faster)"),
    ("+  -", "zoom in (around the cursor) / out"),
    ("0  z", "whole grid / fit to what was seen"),
    ("mouse", "click: inspect a cell, wheel: zoom, drag: pan"),
    ("t", "zoomed in, follow the robot: on / off"),
    ("", "(on by itself once it has moved 0.5 m)"),
    ("Tab 1 2 3", "next view / map / radar / split"),
    ("w", "radar arcs: bin width / beam width"),
    ("o", "walls, corners, posts on the map: on / off"),
    ("s", "save the map as a PNG"),
    ("?", "show or hide this help"),
    ("q  Ctrl-C", "quit"),
];

/// [`KEYS`] as plain text.
pub fn key_help_text() -> String {
    let mut text = String::from("Keys:\n");
    for (key, what) in KEYS {
        text.push_str(&format!("  {key:<12} {what}\n"));
    }
    text
}

/// Something only the main loop can do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    Quit,
    /// Publish on `sonar/commands`.
    Scan(ScanCommand),
    /// Publish on `sonar/fusion_commands`.
    Fusion(FusionCommand),
    /// Save the current grid as a PNG.
    SaveMap,
}

impl Action {
    /// What the action asks for, in words, for the status line and the log.
    pub fn describe(&self) -> String {
        match self {
            Action::Quit => "quit".to_owned(),
            Action::SaveMap => "save the map".to_owned(),
            Action::Scan(cmd) => match cmd.kind() {
                Some(ScanCommandKind::FullScan) => "full scan".to_owned(),
                Some(ScanCommandKind::LocalScan) => {
                    format!("local scan {:+.0}°..{:+.0}°", cmd.from_deg, cmd.to_deg)
                }
                Some(ScanCommandKind::Stop) => "stop".to_owned(),
                Some(ScanCommandKind::Status) => "status request".to_owned(),
                Some(ScanCommandKind::Reset) => "reset the head".to_owned(),
                None => format!("scan command #{}", cmd.kind),
            },
            Action::Fusion(cmd) => match cmd.kind() {
                Some(FusionCommandKind::Clear) => "clear the map".to_owned(),
                Some(FusionCommandKind::SetModel) => {
                    format!("sensor model {}", setting_name(MODELS, cmd.value))
                }
                Some(FusionCommandKind::SetRule) => {
                    format!("combination rule {}", setting_name(RULES, cmd.value))
                }
                Some(FusionCommandKind::SetPreset) => {
                    format!("preset {}", setting_name(PRESETS, cmd.value))
                }
                None => format!("fusion command #{}", cmd.kind),
            },
        }
    }
}

/// What a drawn frame showed, as far as it can change without a terminal event: compared with
/// the app's state now by [`App::needs_redraw`], so an idle viewer draws nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct Drawn {
    revision: u64,
    message: Option<String>,
    ipc_problem: Option<String>,
    driver: Liveness,
    fusion: Liveness,
}

/// What the map shows when the user has not zoomed or panned.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Framing {
    /// What has been seen ([`GridSnapshot::seen_frame`]), growing with the map: the default.
    #[default]
    Seen,
    /// The whole grid (`0`).
    Whole,
}

/// Zoom, pan and cursor of the map.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MapView {
    /// Cells per pixel the user zoomed or panned to; `None`: the framing decides.
    pub scale: Option<f64>,
    pub framing: Framing,
    /// Grid point (x right, y up) in the middle of the picture when zoomed in.
    pub center: (f64, f64),
    /// The cell whose coordinates and probability the status panel shows.
    pub cursor: Option<(u32, u32)>,
    /// Zoomed in, keep the robot in the middle (`center` is moved to it with every grid). The
    /// framed map shows the robot anyway, and stays framed.
    pub follow: bool,
}

impl MapView {
    pub fn viewport(&self, grid: &GridSnapshot, width_px: u32, height_px: u32) -> Viewport {
        match self.scale {
            Some(scale) => Viewport::centred(
                self.center.0,
                self.center.1,
                scale,
                grid.height(),
                width_px,
                height_px,
            ),
            None => self.framed(grid, width_px, height_px),
        }
    }

    /// The picture of the framing alone, whatever the zoom.
    fn framed(&self, grid: &GridSnapshot, width_px: u32, height_px: u32) -> Viewport {
        let frame = match self.framing {
            Framing::Seen => grid.seen_frame(),
            Framing::Whole => CellBox::whole(grid.width(), grid.height()),
        };
        Viewport::framing(&frame, grid.height(), width_px, height_px)
    }

    /// Zoomed or panned by the user.
    pub fn zoomed(&self) -> bool {
        self.scale.is_some()
    }

    fn cursor_center(&self) -> Option<(f64, f64)> {
        self.cursor
            .map(|(x, y)| (f64::from(x) + 0.5, f64::from(y) + 0.5))
    }
}

/// Everything the viewer shows.
#[derive(Debug)]
pub struct App {
    pub view: View,
    pub show_help: bool,
    pub palette: Palette,
    pub grid: Option<GridSnapshot>,
    /// Bumped with every new grid copy, so the renderer knows when to pool again.
    pub grid_generation: u64,
    /// Bumped whenever something shown changed: a snapshot, a status, a reading, a key.
    revision: u64,
    pub radar: Option<Radar>,
    /// The latest walls, corners and posts; `None` until fusion publishes them (it may not).
    pub features: Option<FeaturesSnapshot>,
    /// Draw the features over the map.
    pub show_features: bool,
    pub driver: Option<DriverStatus>,
    pub driver_peer: Peer,
    /// The readings come from `sonar-replay`, not a driver: when they stop, the replay finished.
    pub replay: bool,
    /// The fusion engine's latest counters (`sonar/fusion_status`): readings lost, saves, ….
    pub fusion_status: Option<FusionStatus>,
    /// Where the viewer looks for the pipeline (iceoryx2 prefix and root), said while it waits.
    pub namespace: Option<String>,
    pub fusion_peer: Peer,
    /// The newest readings, newest first.
    pub readings: VecDeque<Reading>,
    pub rate: RateMeter,
    pub map: MapView,
    /// Pixels of the map picture at the last frame (0 × 0 when no map is shown).
    pub map_px: (u32, u32),
    /// The terminal cell showing the map picture's top-left pixel at the last frame.
    pub map_origin: (u16, u16),
    /// Where the left button last was while dragging the map (terminal column, row).
    pub drag_from: Option<(u16, u16)>,
    /// The local-scan segment being chosen, while `l` mode is on.
    pub selection: Option<Segment>,
    /// The last local scan asked for from here (its limits give the sweep progress).
    pub local_segment: Option<Segment>,
    /// Radar arcs as wide as the beam (the paper's picture) instead of one angle bin.
    pub beam_arcs: bool,
    /// The status line: the outcome of the last action.
    pub message: Option<String>,
    /// Why a service could not be opened, if one could not.
    pub ipc_problem: Option<String>,
    /// Angles the head can reach, for the local-scan selection and the sweep progress.
    pub sweep_limits: Segment,
    /// Where the robot has been since the map was last cleared.
    pub trail: Trail,
    /// The latest `sonar/localized_pose`; `None` until the fusion localises (it may not).
    pub localized: Option<LocalizedPose>,
    /// The latest estimate of `sonar-slam` (`sonar/slam_correction`) for a new sweep, revisions
    /// of earlier sweeps left out; `None` until one comes (no `sonar-slam`, or no sweep yet).
    pub slam: Option<SlamCorrection>,
    /// `t` was pressed: the user decides about following, no more automatic switching on.
    pub follow_by_key: bool,
    /// The first position the viewer saw, from which [`AUTO_FOLLOW_M`] is measured.
    pub start_position: Option<(f32, f32)>,
}

impl App {
    pub fn new(palette: Palette, view: View) -> Self {
        let sensor = SensorConfig::default();
        Self {
            view,
            show_help: false,
            palette,
            grid: None,
            grid_generation: 0,
            revision: 0,
            radar: None,
            features: None,
            show_features: true,
            driver: None,
            driver_peer: Peer::default(),
            replay: false,
            fusion_status: None,
            namespace: None,
            fusion_peer: Peer::default(),
            readings: VecDeque::with_capacity(LAST_READINGS + 1),
            rate: RateMeter::default(),
            map: MapView::default(),
            map_px: (0, 0),
            map_origin: (0, 0),
            drag_from: None,
            selection: None,
            local_segment: None,
            beam_arcs: false,
            message: None,
            ipc_problem: None,
            sweep_limits: Segment {
                from_deg: sensor.sweep_min_deg,
                to_deg: sensor.sweep_max_deg,
            },
            trail: Trail::default(),
            localized: None,
            slam: None,
            follow_by_key: false,
            start_position: None,
        }
    }

    /// Takes a copy of a grid snapshot (header and cells as read from shared memory).
    pub fn on_grid(
        &mut self,
        header: &GridHeader,
        cells: &[u8],
        now: Instant,
    ) -> Result<(), String> {
        self.fusion_peer.seen(now);
        check_grid(header, cells.len())?;
        self.revision += 1;
        // Fewer readings than before: the map was cleared (by anyone) or the fusion started afresh,
        // and the path drawn so far belongs to the old map.
        let cleared = self
            .grid
            .as_ref()
            .is_some_and(|g| header.readings_fused < g.header.readings_fused);
        let grid = self.grid.get_or_insert_with(GridSnapshot::default);
        let resized = (grid.header.width, grid.header.height) != (header.width, header.height);
        grid.header = *header;
        grid.cells.clear();
        grid.cells.extend_from_slice(cells);
        grid.seen = seen_box(cells, header.width as usize, header.height as usize);
        let pose = grid.pose();
        self.grid_generation += 1;
        if resized || self.map.cursor.is_none() {
            // A new (or re-sized) map: show all of it, cursor on the sensor.
            let cursor = grid
                .sensor_cell()
                .unwrap_or((header.width / 2, header.height / 2));
            self.map = MapView {
                cursor: Some(cursor),
                follow: self.map.follow,
                ..MapView::default()
            };
        }
        if cleared {
            self.trail.clear();
        }
        if let Some(p) = pose {
            self.trail.push(p.x_m, p.y_m, header.resolution_m);
            let (x0, y0) = *self.start_position.get_or_insert((p.x_m, p.y_m));
            if !self.follow_by_key && (p.x_m - x0).hypot(p.y_m - y0) > AUTO_FOLLOW_M {
                self.map.follow = true;
            }
        }
        self.keep_robot_centred();
        Ok(())
    }

    /// Takes a copy of a `sonar/localized_pose` sample.
    pub fn on_localized_pose(&mut self, fix: &LocalizedPose, now: Instant) -> Result<(), String> {
        self.fusion_peer.seen(now);
        if fix.layout_version != LAYOUT_VERSION {
            return Err(format!(
                "localized pose layout version {} (this viewer reads {LAYOUT_VERSION})",
                fix.layout_version
            ));
        }
        self.localized = Some(*fix);
        self.revision += 1;
        Ok(())
    }

    /// Takes a copy of a `sonar/slam_correction` sample: the estimate of a new sweep is kept, one
    /// that revises an earlier sweep (after a loop closure) is not the state now and is left out.
    pub fn on_slam_correction(&mut self, c: &SlamCorrection) -> Result<(), String> {
        if c.layout_version != LAYOUT_VERSION {
            return Err(format!(
                "SLAM correction layout version {} (this viewer reads {LAYOUT_VERSION})",
                c.layout_version
            ));
        }
        if c.state != slam_state::REVISED {
            self.slam = Some(*c);
            self.revision += 1;
        }
        Ok(())
    }

    pub fn on_radar(&mut self, radar: &Radar, now: Instant) -> Result<(), String> {
        self.fusion_peer.seen(now);
        check_radar(radar)?;
        self.radar = Some(*radar);
        self.revision += 1;
        Ok(())
    }

    /// Takes a copy of a features snapshot (header and records as read from shared memory).
    pub fn on_features(
        &mut self,
        header: &FeaturesHeader,
        records: &[FeatureRecord],
        now: Instant,
    ) -> Result<(), String> {
        self.fusion_peer.seen(now);
        check_features(header, records.len())?;
        let features = self.features.get_or_insert_with(FeaturesSnapshot::default);
        features.header = *header;
        features.records.clear();
        features.records.extend_from_slice(records);
        self.revision += 1;
        Ok(())
    }

    pub fn on_driver_status(&mut self, status: &DriverStatus, now: Instant) -> Result<(), String> {
        self.driver_peer.seen(now);
        if status.layout_version != LAYOUT_VERSION {
            return Err(format!(
                "driver status layout version {}",
                status.layout_version
            ));
        }
        // The driver repeats its status every second; one that says nothing new (only its stamp
        // moved) must not cost an idle viewer a frame.
        let unstamped = |s: &DriverStatus| DriverStatus { stamp_ns: 0, ..*s };
        let shown = (self.driver.as_ref().map(unstamped), self.rate.per_second());
        self.rate.update(status.stamp_ns, status.readings_published);
        self.driver = Some(*status);
        if (self.driver.as_ref().map(unstamped), self.rate.per_second()) != shown {
            self.revision += 1;
        }
        Ok(())
    }

    /// Takes a copy of the fusion engine's counters; a copy that differs only in its stamp (the
    /// once-a-second repeat) costs no frame.
    pub fn on_fusion_status(&mut self, status: &FusionStatus, now: Instant) -> Result<(), String> {
        self.fusion_peer.seen(now);
        if status.layout_version != LAYOUT_VERSION {
            return Err(format!(
                "fusion status layout version {}",
                status.layout_version
            ));
        }
        let unstamped = |s: &FusionStatus| FusionStatus { stamp_ns: 0, ..*s };
        if self.fusion_status.as_ref().map(unstamped) != Some(unstamped(status)) {
            self.revision += 1;
        }
        self.fusion_status = Some(*status);
        Ok(())
    }

    pub fn on_reading(&mut self, reading: &Reading, now: Instant) {
        self.driver_peer.seen(now);
        self.readings.push_front(*reading);
        self.readings.truncate(LAST_READINGS);
        self.revision += 1;
    }

    /// What a frame drawn at `now` shows, for [`Self::needs_redraw`] to compare with later.
    pub fn drawn(&self, now: Instant) -> Drawn {
        Drawn {
            revision: self.revision,
            message: self.message.clone(),
            ipc_problem: self.ipc_problem.clone(),
            driver: self.driver_peer.liveness(now).as_shown(),
            fusion: self.fusion_peer.liveness(now).as_shown(),
        }
    }

    /// Whether a frame drawn at `now` would differ from `last` (none drawn yet: it would). A
    /// terminal event (key, resize) is not app state: the caller draws after one regardless.
    /// While a producer is gone its "gone for N s" ticks, so that costs a frame a second.
    pub fn needs_redraw(&self, now: Instant, last: Option<&Drawn>) -> bool {
        last.is_none_or(|last| *last != self.drawn(now))
    }

    /// Which producers have a publisher whose process is alive, and whether the readings' live
    /// publisher is a replay (`None`: no live publisher of readings, so whoever it was stays).
    pub fn on_publishers(
        &mut self,
        driver_alive: bool,
        fusion_alive: bool,
        replay: Option<bool>,
        now: Instant,
    ) {
        if let Some(replay) = replay
            && replay != self.replay
        {
            self.replay = replay;
            self.revision += 1;
        }
        if driver_alive {
            self.driver_peer.seen(now);
        }
        if fusion_alive {
            self.fusion_peer.seen(now);
        }
    }

    /// The driver's scan mode, from its status (or the radar when the driver has not said).
    pub fn scan_mode(&self) -> ScanMode {
        let from_u32 = |m: u32| u8::try_from(m).map_or(ScanMode::Unknown, ScanMode::from_u8);
        match self.driver.map(|s| from_u32(s.mode)) {
            Some(mode) if mode != ScanMode::Unknown => mode,
            _ => self.radar.map_or(ScanMode::Unknown, |r| from_u32(r.mode)),
        }
    }

    /// The limits of the sweep in progress, if known.
    pub fn sweep_segment(&self) -> Option<Segment> {
        match self.scan_mode() {
            ScanMode::Full => Some(self.sweep_limits),
            ScanMode::Local => self.local_segment,
            ScanMode::Idle | ScanMode::Unknown => None,
        }
    }

    pub fn on_key(&mut self, key: KeyEvent) -> Option<Action> {
        if key.kind == KeyEventKind::Release {
            return None;
        }
        // Nearly every key changes what is shown; the few that do not cost one frame.
        self.revision += 1;
        // Raw mode delivers Ctrl-C as a key, not as SIGINT.
        if key.modifiers.contains(KeyModifiers::CONTROL) && key.code == KeyCode::Char('c') {
            return Some(Action::Quit);
        }
        // The help says any key closes it: `q` too, not the pipeline behind it.
        if self.show_help {
            self.show_help = false;
            return None;
        }
        if key.code == KeyCode::Char('q') {
            return Some(Action::Quit);
        }
        if let Some(selection) = self.selection {
            return self.on_selection_key(selection, key.code);
        }
        let fast = if key.modifiers.contains(KeyModifiers::SHIFT) {
            FAST_STEPS
        } else {
            1
        };
        match key.code {
            KeyCode::Char('?') | KeyCode::F(1) => self.show_help = true,
            KeyCode::Char('f') => return Some(scan(ScanCommandKind::FullScan, None)),
            KeyCode::Char('x') => return Some(scan(ScanCommandKind::Stop, None)),
            KeyCode::Char('R') => return Some(scan(ScanCommandKind::Reset, None)),
            KeyCode::Char('l') => {
                // Start from the last local scan, else around the sweep line.
                let center = self.radar.map_or(0.0, |r| r.current_angle_deg);
                let center = if center.is_finite() { center } else { 0.0 };
                self.selection = Some(
                    self.local_segment
                        .unwrap_or_else(|| Segment::around(center, 30.0, self.sweep_limits)),
                );
                if self.view == View::Map {
                    self.view = View::Split;
                }
            }
            KeyCode::Char('C') => {
                // At once, not when the emptied map arrives: it may not (no fusion listening).
                self.trail.clear();
                return Some(Action::Fusion(FusionCommand::new(
                    FusionCommandKind::Clear,
                    0,
                )));
            }
            KeyCode::Char('m') => {
                return self.next_fusion_setting(FusionCommandKind::SetModel, MODELS, |h| h.model);
            }
            KeyCode::Char('r') => {
                return self.next_fusion_setting(FusionCommandKind::SetRule, RULES, |h| h.rule);
            }
            KeyCode::Char('p') => {
                return self
                    .next_fusion_setting(FusionCommandKind::SetPreset, PRESETS, |h| h.preset);
            }
            KeyCode::Char('s') => return Some(Action::SaveMap),
            KeyCode::Char('w') => self.beam_arcs = !self.beam_arcs,
            KeyCode::Char('o') => self.show_features = !self.show_features,
            KeyCode::Tab => self.view = self.view.next(),
            KeyCode::Char('1') => self.view = View::Map,
            KeyCode::Char('2') => self.view = View::Radar,
            KeyCode::Char('3') => self.view = View::Split,
            KeyCode::Char('+' | '=') => self.zoom(true),
            KeyCode::Char('-') => self.zoom(false),
            KeyCode::Char('0') => self.frame(Framing::Whole),
            KeyCode::Char('z') => self.frame(Framing::Seen),
            KeyCode::Char('t') => self.toggle_follow(),
            KeyCode::Left => self.move_cursor(-1, 0, fast),
            KeyCode::Right => self.move_cursor(1, 0, fast),
            KeyCode::Up => self.move_cursor(0, 1, fast),
            KeyCode::Down => self.move_cursor(0, -1, fast),
            _ => {}
        }
        None
    }

    /// The mouse over the map: a click puts the cursor on the cell under it (the status panel
    /// shows its position and probability), the wheel zooms around it, a drag pans the map.
    pub fn on_mouse(&mut self, mouse: MouseEvent) {
        let at = (mouse.column, mouse.row);
        match mouse.kind {
            MouseEventKind::Down(MouseButton::Left) => {
                let Some((x, y)) = self.under_pointer(at) else {
                    return;
                };
                let inside = self.grid.as_ref().is_some_and(|g| {
                    x >= 0.0 && y >= 0.0 && x < f64::from(g.width()) && y < f64::from(g.height())
                });
                if inside {
                    self.map.cursor = Some((x as u32, y as u32));
                }
                self.drag_from = Some(at);
            }
            MouseEventKind::Drag(MouseButton::Left) => {
                let (Some(from), Some(vp), Some(grid)) =
                    (self.drag_from, self.viewport(), self.grid.as_ref())
                else {
                    return;
                };
                let (cx, cy) = vp.center(grid.height());
                let dx = f64::from(at.0) - f64::from(from.0);
                // Two pixels a row; the map follows the pointer, so the view moves against it.
                let dy = 2.0 * (f64::from(at.1) - f64::from(from.1));
                self.map.scale = Some(vp.scale);
                self.map.center = (cx - dx * vp.scale, cy + dy * vp.scale);
                self.drag_from = Some(at);
                self.stop_following();
            }
            MouseEventKind::Up(_) => self.drag_from = None,
            MouseEventKind::ScrollUp | MouseEventKind::ScrollDown => {
                if let Some(point) = self.under_pointer(at) {
                    self.zoom_at(mouse.kind == MouseEventKind::ScrollUp, Some(point), false);
                }
            }
            _ => return,
        }
        self.revision += 1;
    }

    /// The grid point (continuous, y up) under terminal cell `at` of the map picture; `None` off
    /// the picture or without a map.
    fn under_pointer(&self, (col, row): (u16, u16)) -> Option<(f64, f64)> {
        let (grid, vp) = (self.grid.as_ref()?, self.viewport()?);
        let px = u32::from(col.checked_sub(self.map_origin.0)?);
        // The upper of the terminal cell's two pixels.
        let py = 2 * u32::from(row.checked_sub(self.map_origin.1)?);
        (px < self.map_px.0 && py < self.map_px.1).then(|| vp.grid_point(px, py, grid.height()))
    }

    fn on_selection_key(&mut self, selection: Segment, code: KeyCode) -> Option<Action> {
        let limits = self.sweep_limits;
        match code {
            KeyCode::Left => self.selection = Some(selection.turned(SEGMENT_STEP_DEG, limits)),
            KeyCode::Right => self.selection = Some(selection.turned(-SEGMENT_STEP_DEG, limits)),
            KeyCode::Up => self.selection = Some(selection.widened(SEGMENT_STEP_DEG, limits)),
            KeyCode::Down => self.selection = Some(selection.widened(-SEGMENT_STEP_DEG, limits)),
            KeyCode::Enter => {
                self.selection = None;
                self.local_segment = Some(selection);
                return Some(scan(ScanCommandKind::LocalScan, Some(selection)));
            }
            KeyCode::Esc | KeyCode::Char('l') => self.selection = None,
            _ => {}
        }
        None
    }

    /// Asks the fusion engine for the setting after the one in use (as the grid reports it).
    fn next_fusion_setting(
        &self,
        kind: FusionCommandKind,
        table: &[(u32, &str)],
        in_use: fn(&GridHeader) -> u32,
    ) -> Option<Action> {
        let choices: Vec<u32> = table
            .iter()
            .map(|(code, _)| *code)
            // "custom" is a state the engine reports, not one to ask for.
            .filter(|&code| !(kind == FusionCommandKind::SetPreset && code == preset_code::CUSTOM))
            .collect();
        let current = self.grid.as_ref().map_or(0, |g| in_use(&g.header));
        let value = next_setting(&choices, current);
        Some(Action::Fusion(FusionCommand::new(kind, value)))
    }

    /// `t`: follow the robot or stop following it. Switching it on unzoomed zooms in once, as
    /// following shows nothing new in a framing, which holds the robot anyway.
    fn toggle_follow(&mut self) {
        self.follow_by_key = true;
        self.map.follow = !self.map.follow;
        if self.map.follow && !self.map.zoomed() {
            self.zoom(true);
        }
        self.keep_robot_centred();
        self.message = Some(
            if self.map.follow {
                "following the robot (t: stop)"
            } else {
                "not following the robot (t: follow)"
            }
            .to_owned(),
        );
    }

    /// While following and zoomed in, puts the robot in the middle of the view.
    fn keep_robot_centred(&mut self) {
        if !(self.map.follow && self.map.zoomed()) {
            return;
        }
        if let Some((grid, pose)) = self.grid.as_ref().and_then(|g| g.pose().map(|p| (g, p))) {
            self.map.center = grid.grid_point(pose.x_m, pose.y_m);
        }
    }

    /// The map's picture as the last frame laid it out; `None` without a grid.
    pub fn viewport(&self) -> Option<Viewport> {
        let grid = self.grid.as_ref()?;
        Some(self.map.viewport(grid, self.map_px.0, self.map_px.1))
    }

    /// `0` and `z`: back to a framing, unzoomed.
    fn frame(&mut self, framing: Framing) {
        self.map.scale = None;
        self.map.framing = framing;
    }

    /// `+` and `-`: zooms in around the cursor, or out.
    fn zoom(&mut self, closer: bool) {
        let anchor = if closer {
            self.map.cursor_center()
        } else {
            None
        };
        self.zoom_at(closer, anchor, true);
    }

    /// Zooms by a factor of two: in, to at most [`MAX_PIXELS_PER_CELL`] pixels a cell, or out,
    /// back to the framing once it shows more; zoomed out there, from what was seen to the whole
    /// grid. With `anchor` (a grid point) in the middle if `centred`, else where it is on screen
    /// (the mouse wheel's zoom).
    fn zoom_at(&mut self, closer: bool, anchor: Option<(f64, f64)>, centred: bool) {
        let (w, h) = self.map_px;
        let (Some(grid), Some(vp)) = (self.grid.as_ref(), self.viewport()) else {
            return;
        };
        let (cx, cy) = vp.center(grid.height());
        let finest = 1.0 / MAX_PIXELS_PER_CELL;
        let scale = if closer {
            if vp.scale <= finest * (1.0 + 1e-9) {
                return;
            }
            (vp.scale / 2.0).max(finest)
        } else {
            let framed = self.map.framed(grid, w, h).scale;
            if vp.scale * 2.0 >= framed * (1.0 - 1e-9) {
                if !self.map.zoomed() && self.map.framing == Framing::Seen {
                    self.map.framing = Framing::Whole;
                }
                self.map.scale = None;
                return;
            }
            vp.scale * 2.0
        };
        let ratio = scale / vp.scale;
        self.map.center = match anchor {
            Some(p) if centred => p,
            Some((px, py)) => (px + (cx - px) * ratio, py + (cy - py) * ratio),
            None => (cx, cy),
        };
        self.map.scale = Some(scale);
        self.keep_robot_centred();
    }

    /// Moves the cursor by `steps` pixels (at least one cell); when it leaves the picture the view
    /// re-centres on it, which is how the map pans (and panning ends following the robot).
    fn move_cursor(&mut self, dx: i64, dy: i64, steps: i64) {
        let (Some(grid), Some(vp)) = (self.grid.as_ref(), self.viewport()) else {
            return;
        };
        let (gw, gh) = (grid.width(), grid.height());
        let cells_per_step = (vp.scale.round() as i64).max(1) * steps;
        let (x, y) = self.map.cursor.unwrap_or((gw / 2, gh / 2));
        let clamp = |v: i64, n: u32| v.clamp(0, i64::from(n) - 1) as u32;
        let cursor = (
            clamp(i64::from(x) + dx * cells_per_step, gw),
            clamp(i64::from(y) + dy * cells_per_step, gh),
        );
        self.map.cursor = Some(cursor);
        if vp.pixel_of(cursor.0, cursor.1, gh).is_none()
            && let Some(c) = self.map.cursor_center()
        {
            self.stop_following();
            // Out of the framed picture too: the view takes over at its scale and pans.
            self.map.scale = Some(vp.scale);
            self.map.center = c;
        }
    }

    /// The user took the view over: following ends, and does not switch itself on again.
    fn stop_following(&mut self) {
        if self.map.follow {
            self.map.follow = false;
            self.follow_by_key = true;
            self.message = Some("not following the robot (t: follow)".to_owned());
        }
    }
}

fn scan(kind: ScanCommandKind, segment: Option<Segment>) -> Action {
    let (from, to) = segment.map_or((0.0, 0.0), |s| (s.from_deg, s.to_deg));
    Action::Scan(ScanCommand::new(kind, from, to))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::heatmap::ColorMode;
    use sonar_common::ipc::{CELL_UNKNOWN, model_code, rule_code};

    fn key(code: KeyCode) -> KeyEvent {
        KeyEvent::new(code, KeyModifiers::NONE)
    }

    fn app() -> App {
        App::new(Palette::new(ColorMode::TrueColor), View::Split)
    }

    fn grid_header(w: u32, h: u32) -> GridHeader {
        GridHeader {
            layout_version: LAYOUT_VERSION,
            width: w,
            height: h,
            resolution_m: 0.05,
            origin_x_m: -(w as f32) * 0.025,
            origin_y_m: -(h as f32) * 0.025,
            model: model_code::PAPER,
            rule: rule_code::HIMM,
            preset: preset_code::CUSTOM,
            ..GridHeader::default()
        }
    }

    #[test]
    fn quit_keys() {
        let mut app = app();
        assert_eq!(app.on_key(key(KeyCode::Char('q'))), Some(Action::Quit));
        let ctrl_c = KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL);
        assert_eq!(app.on_key(ctrl_c), Some(Action::Quit));
        // With the help open, `q` closes the help (it says any key does); Ctrl-C still quits.
        app.show_help = true;
        assert_eq!(app.on_key(key(KeyCode::Char('q'))), None);
        assert!(!app.show_help);
        app.show_help = true;
        assert_eq!(app.on_key(ctrl_c), Some(Action::Quit));
    }

    #[test]
    fn scan_keys_make_driver_commands() {
        let mut app = app();
        let Some(Action::Scan(cmd)) = app.on_key(key(KeyCode::Char('f'))) else {
            panic!("f should start a full scan");
        };
        assert_eq!(cmd.kind(), Some(ScanCommandKind::FullScan));
        let Some(Action::Scan(cmd)) = app.on_key(key(KeyCode::Char('x'))) else {
            panic!("x should stop");
        };
        assert_eq!(cmd.kind(), Some(ScanCommandKind::Stop));
    }

    #[test]
    fn local_scan_is_chosen_with_arrows_and_sent_with_enter() {
        let mut app = app();
        app.view = View::Map;
        assert_eq!(app.on_key(key(KeyCode::Char('l'))), None);
        assert_eq!(app.view, View::Split, "the radar must be visible to choose");
        assert_eq!(
            app.selection,
            Some(Segment {
                from_deg: -30.0,
                to_deg: 30.0
            })
        );
        app.on_key(key(KeyCode::Left)); // turn counter-clockwise
        app.on_key(key(KeyCode::Down)); // narrow
        // While choosing, f is not a full scan.
        assert_eq!(app.on_key(key(KeyCode::Char('f'))), None);
        let Some(Action::Scan(cmd)) = app.on_key(key(KeyCode::Enter)) else {
            panic!("Enter should send the local scan");
        };
        assert_eq!(cmd.kind(), Some(ScanCommandKind::LocalScan));
        assert_eq!((cmd.from_deg, cmd.to_deg), (-18.0, 30.0));
        assert_eq!(Action::Scan(cmd).describe(), "local scan -18°..+30°");
        assert_eq!(app.selection, None);
        assert_eq!(app.local_segment.map(|s| s.to_deg), Some(30.0));
        // The next selection starts from the segment just scanned.
        app.on_key(key(KeyCode::Char('l')));
        assert_eq!(app.selection, app.local_segment);
    }

    #[test]
    fn selection_stays_within_the_sweep_and_a_minimum_width() {
        let limits = Segment {
            from_deg: -150.0,
            to_deg: 150.0,
        };
        let mut s = Segment::around(140.0, 30.0, limits);
        assert_eq!((s.from_deg, s.to_deg), (90.0, 150.0));
        for _ in 0..100 {
            s = s.widened(-SEGMENT_STEP_DEG, limits);
        }
        assert_eq!(s.to_deg - s.from_deg, SEGMENT_MIN_WIDTH_DEG);
        for _ in 0..100 {
            s = s.turned(-SEGMENT_STEP_DEG, limits);
        }
        assert_eq!(s.from_deg, -150.0);
        for _ in 0..100 {
            s = s.widened(SEGMENT_STEP_DEG, limits);
        }
        assert_eq!((s.from_deg, s.to_deg), (-150.0, 150.0));
    }

    #[test]
    fn escape_cancels_the_selection() {
        let mut app = app();
        app.on_key(key(KeyCode::Char('l')));
        assert_eq!(app.on_key(key(KeyCode::Esc)), None);
        assert_eq!(app.selection, None);
        assert_eq!(app.local_segment, None);
    }

    #[test]
    fn fusion_keys_cycle_from_the_settings_in_use() {
        let mut app = app();
        let t = Instant::now();
        app.on_grid(&grid_header(4, 4), &[0; 16], t).unwrap();
        let fusion = |a: Option<Action>| match a {
            Some(Action::Fusion(c)) => (c.kind(), c.value),
            other => panic!("expected a fusion command, got {other:?}"),
        };
        assert_eq!(
            fusion(app.on_key(key(KeyCode::Char('m')))),
            (Some(FusionCommandKind::SetModel), model_code::LOG_ODDS)
        );
        // HIMM is the last rule: wrap to the first.
        assert_eq!(
            fusion(app.on_key(key(KeyCode::Char('r')))),
            (Some(FusionCommandKind::SetRule), rule_code::BAYES)
        );
        // From "custom", the first selectable preset; "custom" itself is never sent.
        assert_eq!(
            fusion(app.on_key(key(KeyCode::Char('p')))),
            (Some(FusionCommandKind::SetPreset), preset_code::PAPER)
        );
        assert_eq!(
            next_setting(
                &[preset_code::PAPER, preset_code::RECOMMENDED],
                preset_code::RECOMMENDED
            ),
            preset_code::PAPER
        );
        assert_eq!(
            fusion(app.on_key(key(KeyCode::Char('C')))),
            (Some(FusionCommandKind::Clear), 0)
        );
        assert_eq!(setting_name(RULES, 99), "#99");
        let himm = Action::Fusion(FusionCommand::new(
            FusionCommandKind::SetRule,
            rule_code::HIMM,
        ));
        assert_eq!(himm.describe(), "combination rule HIMM");
    }

    #[test]
    fn views_and_help() {
        let mut app = app();
        app.on_key(key(KeyCode::Char('1')));
        assert_eq!(app.view, View::Map);
        app.on_key(key(KeyCode::Tab));
        assert_eq!(app.view, View::Radar);
        app.on_key(key(KeyCode::Char('?')));
        assert!(app.show_help);
        // Any key closes the help without acting, `q` included.
        assert_eq!(app.on_key(key(KeyCode::Char('f'))), None);
        assert!(!app.show_help);
        app.on_key(key(KeyCode::Char('?')));
        assert_eq!(app.on_key(key(KeyCode::Char('q'))), None);
        assert!(!app.show_help);
        assert_eq!(app.on_key(key(KeyCode::Char('q'))), Some(Action::Quit));
    }

    #[test]
    fn cursor_moves_by_a_pixel_and_zoom_pans_to_it() {
        let mut app = app();
        let t = Instant::now();
        app.on_grid(&grid_header(400, 200), &vec![0; 400 * 200], t)
            .unwrap();
        app.map_px = (100, 50); // 4 cells per pixel at the fitting zoom
        assert_eq!(app.map.cursor, Some((200, 100)), "starts on the sensor");
        app.on_key(key(KeyCode::Right));
        assert_eq!(app.map.cursor, Some((204, 100)));
        app.on_key(KeyEvent::new(KeyCode::Up, KeyModifiers::SHIFT));
        assert_eq!(app.map.cursor, Some((204, 132)));
        app.on_key(key(KeyCode::Char('+')));
        assert_eq!(app.map.scale, Some(2.0));
        assert_eq!(app.map.center, (204.5, 132.5));
        // Far to the left, out of the zoomed picture: the view follows.
        for _ in 0..20 {
            app.on_key(KeyEvent::new(KeyCode::Left, KeyModifiers::SHIFT));
        }
        assert_eq!(app.map.cursor, Some((0, 132)));
        let vp = app.viewport().unwrap();
        assert!(vp.pixel_of(0, 132, 200).is_some(), "{vp:?}");
        // Zooming stops at MAX_PIXELS_PER_CELL pixels per cell: fit 4 → 1/8 is 5 halvings.
        for _ in 0..10 {
            app.on_key(key(KeyCode::Char('+')));
        }
        assert_eq!(app.map.scale, Some(0.125));
        app.on_key(key(KeyCode::Char('0')));
        assert_eq!((app.map.scale, app.map.framing), (None, Framing::Whole));
    }

    /// Issue 16: the map frames what has been seen (and the sensor), not the whole grid; `-`
    /// goes on to the whole grid, `z` back, `0` to the whole grid at once.
    #[test]
    fn the_map_frames_what_was_seen_until_asked_for_the_whole_grid() {
        let mut viewer = app();
        let t = Instant::now();
        let (w, h) = (400usize, 200usize);
        let mut cells = vec![CELL_UNKNOWN; w * h];
        for y in 50..70 {
            cells[y * w + 100..y * w + 140].fill(0);
        }
        viewer.on_grid(&grid_header(400, 200), &cells, t).unwrap();
        viewer.map_px = (100, 50); // 4 cells per pixel for the whole grid
        let seen = viewer.grid.as_ref().unwrap().seen.unwrap();
        assert_eq!(
            (seen.x0, seen.y0, seen.x1, seen.y1),
            (100.0, 50.0, 140.0, 70.0)
        );
        let vp = viewer.viewport().unwrap();
        assert!(
            vp.scale < 1.3,
            "the seen part and the sensor fill the picture: {vp:?}"
        );
        for (x, y) in [(100, 50), (139, 69), (200, 100)] {
            assert!(
                vp.pixel_of(x, y, 200).is_some(),
                "cell ({x}, {y}) shown: {vp:?}"
            );
        }
        // `-` from the framing: the whole grid; further out there is nothing.
        viewer.on_key(key(KeyCode::Char('-')));
        assert_eq!(
            (viewer.map.scale, viewer.map.framing),
            (None, Framing::Whole)
        );
        assert_eq!(viewer.viewport().unwrap().scale, 4.0);
        viewer.on_key(key(KeyCode::Char('-')));
        assert_eq!(viewer.viewport().unwrap().scale, 4.0);
        // `z` frames the seen part again; `+` zooms in from there, `-` comes back to it.
        viewer.on_key(key(KeyCode::Char('z')));
        assert_eq!(viewer.viewport().unwrap(), vp);
        viewer.on_key(key(KeyCode::Char('+')));
        assert_eq!(viewer.map.scale, Some(vp.scale / 2.0));
        viewer.on_key(key(KeyCode::Char('-')));
        assert_eq!(
            (viewer.map.scale, viewer.map.framing),
            (None, Framing::Seen)
        );
        viewer.on_key(key(KeyCode::Char('0')));
        assert_eq!(viewer.viewport().unwrap().scale, 4.0);
        assert!(key_help_text().contains("0  z         whole grid / fit to what was seen"));

        // Nothing seen yet: the whole grid; a couple of cells: at least MIN_FRAME_M across.
        let mut fresh = app();
        let mut cells = vec![CELL_UNKNOWN; w * h];
        fresh.on_grid(&grid_header(400, 200), &cells, t).unwrap();
        fresh.map_px = (100, 50);
        assert_eq!(fresh.viewport().unwrap().scale, 4.0);
        cells[100 * w + 201] = 0;
        fresh.on_grid(&grid_header(400, 200), &cells, t).unwrap();
        let vp = fresh.viewport().unwrap();
        assert!(
            (vp.scale - 40.0 / 50.0).abs() < 1e-9,
            "2 m of 5 cm cells in 50 px: {vp:?}"
        );
    }

    fn mouse(kind: MouseEventKind, column: u16, row: u16) -> MouseEvent {
        MouseEvent {
            kind,
            column,
            row,
            modifiers: KeyModifiers::NONE,
        }
    }

    /// Issue 16: a click inspects the cell under the pointer, the wheel zooms around the pointer,
    /// a drag pans the map.
    #[test]
    fn the_mouse_inspects_zooms_and_pans() {
        let mut viewer = app();
        let t = Instant::now();
        viewer
            .on_grid(&grid_header(400, 200), &vec![0; 400 * 200], t)
            .unwrap();
        viewer.map_px = (100, 50);
        viewer.map_origin = (2, 1);
        let vp = viewer.viewport().unwrap();
        // Column 52, row 13: pixel (50, 24).
        let (gx, gy) = vp.grid_point(50, 24, 200);
        viewer.on_mouse(mouse(MouseEventKind::Down(MouseButton::Left), 52, 13));
        viewer.on_mouse(mouse(MouseEventKind::Up(MouseButton::Left), 52, 13));
        assert_eq!(viewer.map.cursor, Some((gx as u32, gy as u32)));
        // Off the picture (its border, the other view): nothing moves.
        viewer.on_mouse(mouse(MouseEventKind::Down(MouseButton::Left), 1, 0));
        viewer.on_mouse(mouse(MouseEventKind::Down(MouseButton::Left), 102, 13));
        viewer.on_mouse(mouse(MouseEventKind::ScrollUp, 60, 40));
        assert_eq!(viewer.map.cursor, Some((gx as u32, gy as u32)));
        assert_eq!(viewer.viewport(), Some(vp));

        // The wheel zooms in by two, the point under the pointer staying under it.
        viewer.on_mouse(mouse(MouseEventKind::ScrollUp, 52, 13));
        let zoomed = viewer.viewport().unwrap();
        assert_eq!(zoomed.scale, vp.scale / 2.0);
        let (zx, zy) = zoomed.grid_point(50, 24, 200);
        assert!((zx - gx).abs() < 1e-9 && (zy - gy).abs() < 1e-9);

        // Dragged 5 columns right and 2 rows down, the map moves with the pointer.
        let (cx, cy) = zoomed.center(200);
        viewer.on_mouse(mouse(MouseEventKind::Down(MouseButton::Left), 52, 13));
        viewer.on_mouse(mouse(MouseEventKind::Drag(MouseButton::Left), 55, 14));
        viewer.on_mouse(mouse(MouseEventKind::Drag(MouseButton::Left), 57, 15));
        viewer.on_mouse(mouse(MouseEventKind::Up(MouseButton::Left), 57, 15));
        let (px, py) = viewer.viewport().unwrap().center(200);
        let s = zoomed.scale;
        assert!((px - (cx - 5.0 * s)).abs() < 1e-9, "{px} {cx}");
        assert!((py - (cy + 4.0 * s)).abs() < 1e-9, "{py} {cy}");
        // A drag without a press first does nothing.
        viewer.on_mouse(mouse(MouseEventKind::Drag(MouseButton::Left), 80, 20));
        assert_eq!(viewer.viewport().unwrap().center(200), (px, py));

        // The wheel back out returns to the framing.
        viewer.on_mouse(mouse(MouseEventKind::ScrollDown, 52, 13));
        assert_eq!(viewer.map.scale, None);
    }

    #[test]
    fn liveness_waits_then_lives_then_goes() {
        let t = Instant::now();
        let mut peer = Peer::default();
        assert_eq!(peer.liveness(t), Liveness::Waiting);
        peer.seen(t);
        assert_eq!(peer.liveness(t + PEER_TIMEOUT), Liveness::Alive);
        let later = t + PEER_TIMEOUT + Duration::from_secs(2);
        assert_eq!(
            peer.liveness(later),
            Liveness::Gone(PEER_TIMEOUT + Duration::from_secs(2))
        );
        peer.seen(later);
        assert_eq!(peer.liveness(later), Liveness::Alive);
    }

    #[test]
    fn bad_snapshots_are_refused() {
        let mut app = app();
        let t = Instant::now();
        assert!(app.on_grid(&grid_header(4, 4), &[0; 15], t).is_err());
        let mut old = grid_header(4, 4);
        old.layout_version = 0;
        assert!(app.on_grid(&old, &[0; 16], t).is_err());
        let mut zero_res = grid_header(4, 4);
        zero_res.resolution_m = 0.0;
        assert!(app.on_grid(&zero_res, &[0; 16], t).is_err());
        assert!(app.grid.is_none());
        // A refused snapshot still shows that fusion is there.
        assert_eq!(app.fusion_peer.liveness(t), Liveness::Alive);
        let radar = Radar {
            bin_count: 400,
            ..Radar::default()
        };
        assert!(app.on_radar(&radar, t).is_err());
    }

    fn features_header(count: u32) -> FeaturesHeader {
        FeaturesHeader {
            layout_version: LAYOUT_VERSION,
            feature_count: count,
            sweeps: 4,
            ..FeaturesHeader::default()
        }
    }

    #[test]
    fn features_are_copied_and_bad_ones_refused() {
        let mut app = app();
        let t = Instant::now();
        let post = FeatureRecord {
            kind: sonar_common::ipc::feature_kind::POINT,
            x_m: 1.0,
            y_m: 0.5,
            ..FeatureRecord::default()
        };
        // Fewer records than announced, and more than announced.
        assert!(app.on_features(&features_header(2), &[post], t).is_err());
        assert!(app.on_features(&features_header(0), &[post], t).is_err());
        let mut old = features_header(1);
        old.layout_version = 0;
        assert!(app.on_features(&old, &[post], t).is_err());
        let too_many = vec![post; MAX_FEATURES + 1];
        let count = u32::try_from(too_many.len()).unwrap();
        assert!(
            app.on_features(&features_header(count), &too_many, t)
                .is_err()
        );
        assert!(app.features.is_none());
        assert_eq!(app.fusion_peer.liveness(t), Liveness::Alive);

        app.on_features(&features_header(1), &[post], t).unwrap();
        let copy = app.features.as_ref().unwrap();
        assert_eq!(
            (copy.header.sweeps, copy.records.as_slice()),
            (4, &[post][..])
        );
        // A clear publishes an empty snapshot: nothing is left over from before.
        app.on_features(&features_header(0), &[], t).unwrap();
        assert!(app.features.as_ref().unwrap().records.is_empty());
    }

    #[test]
    fn o_toggles_the_features_overlay() {
        let mut app = app();
        assert!(app.show_features, "on by default");
        assert_eq!(app.on_key(key(KeyCode::Char('o'))), None);
        assert!(!app.show_features);
        app.on_key(key(KeyCode::Char('o')));
        assert!(app.show_features);
        // While the help is open the key only closes it.
        app.show_help = true;
        app.on_key(key(KeyCode::Char('o')));
        assert!(app.show_features && !app.show_help);
        assert!(key_help_text().contains("o            walls, corners, posts"));
    }

    #[test]
    fn rate_from_the_driver_counter() {
        let mut rate = RateMeter::default();
        rate.update(10_000_000_000, 100);
        assert_eq!(rate.per_second(), None);
        rate.update(10_500_000_000, 102); // too soon: keep the reference
        assert_eq!(rate.per_second(), None);
        rate.update(12_000_000_000, 110);
        assert_eq!(rate.per_second(), Some(5.0));
        rate.update(13_000_000_000, 3); // restarted driver
        assert_eq!(rate.per_second(), None);
    }

    #[test]
    fn sweep_progress_follows_the_direction() {
        let limits = Segment {
            from_deg: -150.0,
            to_deg: 150.0,
        };
        let near = |a: Option<f32>, b: f32| a.is_some_and(|a| (a - b).abs() < 1e-6);
        assert!(near(sweep_progress(-150.0, 1, limits), 0.0));
        assert!(near(sweep_progress(0.0, 1, limits), 0.5));
        assert!(near(sweep_progress(90.0, -1, limits), 0.2));
        assert_eq!(sweep_progress(0.0, 0, limits), None);
    }

    /// A 4 m × 4 m grid of 5 cm cells around the origin with the sensor at (`x`, `y`), `theta`.
    fn grid_at(x: f32, y: f32, theta: f32, fused: u64) -> GridHeader {
        GridHeader {
            pose_x_m: x,
            pose_y_m: y,
            pose_theta_rad: theta,
            readings_fused: fused,
            ..grid_header(80, 80)
        }
    }

    #[test]
    fn the_trail_keeps_positions_a_cell_apart_and_the_last_500() {
        let mut trail = Trail::default();
        assert!(trail.push(0.0, 0.0, 0.05));
        // Standing still, or moving within a cell: nothing new.
        assert!(!trail.push(0.0, 0.0, 0.05));
        assert!(!trail.push(0.03, 0.03, 0.05));
        assert!(trail.push(0.06, 0.0, 0.05));
        assert!(!trail.push(f32::NAN, 0.0, 0.05));
        assert!(!trail.push(0.0, f32::INFINITY, 0.05));
        assert_eq!(
            trail.points().collect::<Vec<_>>(),
            [(0.0, 0.0), (0.06, 0.0)]
        );
        for i in 0..TRAIL_LEN {
            trail.push(1.0 + 0.1 * i as f32, 0.0, 0.05);
        }
        let points: Vec<_> = trail.points().collect();
        assert_eq!(points.len(), TRAIL_LEN);
        assert_eq!(points.first(), Some(&(1.0, 0.0)), "the oldest went");
        trail.clear();
        assert_eq!(trail.points().count(), 0);
    }

    #[test]
    fn the_trail_grows_with_the_grids_pose_and_is_cleared_with_the_map() {
        let mut app = app();
        let t = Instant::now();
        let cells = vec![0; 80 * 80];
        for (i, x) in [0.0, 0.02, 0.1, 0.2, 0.3].into_iter().enumerate() {
            app.on_grid(&grid_at(x, 0.0, 0.0, 10 * i as u64), &cells, t)
                .unwrap();
        }
        let xs: Vec<f32> = app.trail.points().map(|p| p.0).collect();
        assert_eq!(xs, [0.0, 0.1, 0.2, 0.3], "0.02 m is within a cell");
        // Fewer readings fused than before: the map was cleared, the path starts again.
        app.on_grid(&grid_at(0.4, 0.0, 0.0, 5), &cells, t).unwrap();
        assert_eq!(app.trail.points().collect::<Vec<_>>(), [(0.4, 0.0)]);
        // A non-finite pose adds nothing and draws no marker.
        app.on_grid(&grid_at(f32::NAN, 0.0, 0.0, 6), &cells, t)
            .unwrap();
        assert_eq!(app.trail.points().count(), 1);
        assert_eq!(app.grid.as_ref().unwrap().pose(), None);
        // `C` clears it at once, before the emptied map arrives.
        app.on_grid(&grid_at(0.6, 0.0, 0.0, 7), &cells, t).unwrap();
        assert_eq!(app.trail.points().count(), 2);
        assert!(matches!(
            app.on_key(key(KeyCode::Char('C'))),
            Some(Action::Fusion(_))
        ));
        assert_eq!(app.trail.points().count(), 0);
    }

    #[test]
    fn t_keeps_the_robot_in_the_middle_of_the_zoomed_map() {
        let mut app = app();
        let t = Instant::now();
        let cells = vec![0; 80 * 80];
        app.on_grid(&grid_at(0.0, 0.0, 0.0, 1), &cells, t).unwrap();
        app.map_px = (40, 40); // 2 cells per pixel at the fitting zoom
        assert!(!app.map.follow, "a fixed head is not followed");
        // Over the whole map, following zooms in once, around the robot: cell (40, 40) at the
        // origin, continuous grid point (40, 40).
        assert_eq!(app.on_key(key(KeyCode::Char('t'))), None);
        assert!(app.map.follow);
        assert_eq!(app.map.scale, Some(1.0));
        assert_eq!(app.map.center, (40.0, 40.0));
        assert!(app.message.as_deref().unwrap().starts_with("following"));
        // Each grid moves the view with the robot.
        app.on_grid(&grid_at(0.5, -0.25, 1.0, 2), &cells, t)
            .unwrap();
        assert_eq!(app.map.center, (50.0, 35.0));
        // Zooming in further stays on the robot, not on the cursor.
        app.on_key(key(KeyCode::Char('+')));
        assert_eq!((app.map.scale, app.map.center), (Some(0.5), (50.0, 35.0)));
        // Off: the view stays where it is while the robot drives on.
        app.on_key(key(KeyCode::Char('t')));
        assert!(!app.map.follow);
        app.on_grid(&grid_at(1.0, 0.0, 1.0, 3), &cells, t).unwrap();
        assert_eq!(app.map.center, (50.0, 35.0));
        assert!(key_help_text().contains("t            zoomed in, follow the robot"));
    }

    #[test]
    fn panning_away_ends_following() {
        let mut app = app();
        let t = Instant::now();
        let cells = vec![0; 80 * 80];
        app.on_grid(&grid_at(0.0, 0.0, 0.0, 1), &cells, t).unwrap();
        app.map_px = (40, 40);
        app.on_key(key(KeyCode::Char('t')));
        app.on_key(key(KeyCode::Char('+')));
        // Within the picture the cursor moves and the view stays on the robot.
        app.on_key(key(KeyCode::Right));
        assert!(app.map.follow);
        for _ in 0..10 {
            app.on_key(KeyEvent::new(KeyCode::Right, KeyModifiers::SHIFT));
        }
        assert!(!app.map.follow, "the user took the view over");
        assert_ne!(app.map.center, (40.0, 40.0));
        app.on_grid(&grid_at(0.5, 0.0, 0.0, 2), &cells, t).unwrap();
        assert!(!app.map.follow, "and it does not switch on again by itself");
    }

    #[test]
    fn a_robot_that_moves_half_a_metre_is_followed_unless_t_said_otherwise() {
        let cells = vec![0; 80 * 80];
        let t = Instant::now();
        let mut robot = app();
        robot
            .on_grid(&grid_at(1.0, 1.0, 0.0, 1), &cells, t)
            .unwrap();
        robot
            .on_grid(&grid_at(1.3, 1.3, 0.0, 2), &cells, t)
            .unwrap();
        assert!(!robot.map.follow, "0.42 m from the start");
        robot
            .on_grid(&grid_at(1.4, 1.4, 0.0, 3), &cells, t)
            .unwrap();
        assert!(robot.map.follow, "0.57 m from the start");
        assert_eq!(robot.map.scale, None, "the framed map stays framed");

        let mut by_hand = app();
        by_hand
            .on_grid(&grid_at(1.0, 1.0, 0.0, 1), &cells, t)
            .unwrap();
        by_hand.on_key(key(KeyCode::Char('t')));
        by_hand.on_key(key(KeyCode::Char('t')));
        by_hand
            .on_grid(&grid_at(2.0, 1.0, 0.0, 2), &cells, t)
            .unwrap();
        assert!(!by_hand.map.follow, "switched off by hand");
    }

    #[test]
    fn localized_poses_are_copied_and_other_layouts_refused() {
        let mut app = app();
        let t = Instant::now();
        let fix = LocalizedPose {
            layout_version: LAYOUT_VERSION,
            matched: 3,
            ..LocalizedPose::default()
        };
        let old = LocalizedPose {
            layout_version: 0,
            ..fix
        };
        assert!(app.on_localized_pose(&old, t).is_err());
        assert_eq!(app.localized, None);
        assert_eq!(app.fusion_peer.liveness(t), Liveness::Alive);
        app.on_localized_pose(&fix, t).unwrap();
        assert_eq!(app.localized, Some(fix));
    }

    #[test]
    fn world_and_cell_coordinates_agree() {
        let grid = GridSnapshot {
            header: grid_header(100, 80),
            cells: vec![0; 8000],
            seen: None,
        };
        assert_eq!(grid.sensor_cell(), Some((50, 40)));
        let (x, y) = grid.cell_center_m(10, 70);
        assert_eq!(grid.cell_at_m(x, y), Some((10, 70)));
        assert_eq!(grid.cell_at_m(100.0, 0.0), None);
    }

    /// An idle viewer draws nothing: only what would change the picture asks for a frame.
    #[test]
    fn a_frame_is_needed_only_when_what_it_shows_changed() {
        let t0 = Instant::now();
        let mut viewer = app();
        assert!(viewer.needs_redraw(t0, None), "the first frame");
        let status = DriverStatus {
            layout_version: LAYOUT_VERSION,
            stamp_ns: 1_000_000_000,
            readings_published: 40,
            ..DriverStatus::default()
        };
        viewer.on_driver_status(&status, t0).unwrap();
        viewer.on_publishers(true, true, None, t0);
        let drawn = viewer.drawn(t0);
        assert!(!viewer.needs_redraw(t0, Some(&drawn)));

        // The driver repeats its status a second later, nothing else new; the liveness check
        // finds both producers alive: nothing to draw.
        let t1 = t0 + Duration::from_secs(1);
        let repeated = DriverStatus {
            stamp_ns: 2_000_000_000,
            ..status
        };
        viewer.on_driver_status(&repeated, t1).unwrap();
        viewer.on_publishers(true, true, None, t1);
        let drawn = viewer.drawn(t1);
        let t2 = t1 + Duration::from_secs(1);
        viewer
            .on_driver_status(
                &DriverStatus {
                    stamp_ns: 3_000_000_000,
                    ..status
                },
                t2,
            )
            .unwrap();
        viewer.on_publishers(true, true, None, t2);
        assert!(!viewer.needs_redraw(t2, Some(&drawn)));

        // A status that says something new does.
        let scanning = DriverStatus {
            stamp_ns: 4_000_000_000,
            sweep_id: 3,
            ..status
        };
        viewer.on_driver_status(&scanning, t2).unwrap();
        assert!(viewer.needs_redraw(t2, Some(&drawn)));
        let drawn = viewer.drawn(t2);

        // So does every snapshot, reading and key, and a new message or IPC problem.
        let changes: [&dyn Fn(&mut App); 8] = [
            &|a| a.on_grid(&grid_header(4, 4), &[0; 16], t2).unwrap(),
            &|a| {
                a.on_radar(
                    &Radar {
                        layout_version: LAYOUT_VERSION,
                        ..Radar::default()
                    },
                    t2,
                )
                .unwrap()
            },
            &|a| {
                let header = FeaturesHeader {
                    layout_version: LAYOUT_VERSION,
                    ..FeaturesHeader::default()
                };
                a.on_features(&header, &[], t2).unwrap();
            },
            &|a| {
                let fix = LocalizedPose {
                    layout_version: LAYOUT_VERSION,
                    ..LocalizedPose::default()
                };
                a.on_localized_pose(&fix, t2).unwrap();
            },
            &|a| a.on_reading(&Reading::default(), t2),
            &|a| {
                a.on_key(key(KeyCode::Tab));
            },
            &|a| a.message = Some("saved".to_owned()),
            &|a| a.ipc_problem = Some("open sonar/grid: incompatible".to_owned()),
        ];
        for (i, change) in changes.iter().enumerate() {
            let mut changed = app();
            changed.on_driver_status(&scanning, t2).unwrap();
            changed.on_publishers(true, true, None, t2);
            let before = changed.drawn(t2);
            change(&mut changed);
            assert!(changed.needs_redraw(t2, Some(&before)), "change {i}");
        }

        // A producer falls silent: a frame when it turns "gone", then one per second as its
        // "gone for N s" counts, none in between.
        let silent_from = t2;
        let gone = silent_from + PEER_TIMEOUT + Duration::from_millis(100);
        assert!(!viewer.needs_redraw(silent_from + PEER_TIMEOUT, Some(&drawn)));
        assert!(viewer.needs_redraw(gone, Some(&drawn)));
        let drawn = viewer.drawn(gone);
        assert!(!viewer.needs_redraw(gone + Duration::from_millis(800), Some(&drawn)));
        assert!(viewer.needs_redraw(gone + Duration::from_secs(1), Some(&drawn)));
    }
}
