//! `sonar-sim`: the paper's sonar head — PIC microcontroller, geared stepper between two limit
//! switches, SRF05 — in software, behind a pseudo-terminal, so the driver runs exactly as on the
//! hardware.
//!
//! # Design
//!
//! Three pure layers and one thin I/O layer:
//!
//! - [`firmware`]: the microcontroller as a state machine. Host lines in, [`DeviceMessage`]s out,
//!   on a **simulated** millisecond clock: every behaviour is deterministic and unit-tested without
//!   wall time.
//! - [`echo`]: the physics. For a ping aimed at an angle, every echo the scene returns, its range
//!   and level; the first one above the detection threshold is what the SRF05 reports, with seeded
//!   noise.
//! - [`scene`]: walls, polygons and posts from TOML/JSON files or the built-in scenes (the
//!   paper's Figs. 8–11, and two with a robot touring them), with their ground truth for
//!   evaluation.
//! - [`robot`]: the robot carrying the head along the scene's `[robot]` path, on the simulated
//!   clock (driving on or stopping for a sweep at each waypoint), and its wheel odometry with
//!   seeded errors. `sonar-sim` publishes the odometry on `robot/pose` and the truth on
//!   `robot/true_pose`; each ping is taken from the pose of its own instant.
//! - [`serve`](mod@serve): the pseudo-terminal and the loop that paces simulated time against wall time.
//!   [`hobby`] is the alternative firmware of the `--dialect hobby` mode; [`link`] the `--link`
//!   symbolic link to the terminal.
//! - [`faults`]: `--faults`, between the device and the terminal: damaged lines (garbage, bit flips,
//!   same-column double flips, truncation, overlong lines, stray bytes), a reset mid-sweep and
//!   silences, seeded and logged, to test a driver against a noisy line; and broken limit
//!   switches ([`SwitchFault`]: `min-switch=`/`max-switch=` `dead`, `stuck`, `early:DEG`,
//!   `bouncing`), which the model plays. Pure, like the model.
//!
//! # Device behaviour (protocol version 2, `docs/protocol.md`; version 1 with `--protocol 1`)
//!
//! - **Power-on**: the head has homed to the MIN limit (−150°); the switch reversed the motor, so
//!   the direction is `+` (CCW). Idle; `ST,IDLE,-15000,+,0`. The model homes instantly: no
//!   `HOMING` state and no `LIM,MIN`, which the firmware (and `sonar-firmware-sim`) report while
//!   the head turns to find its switch.
//! - At power-on (version 2) the head announces itself with its `HELLO` line, unprompted.
//! - **Reset** ([`Firmware::reset`], `--faults reset=…`): as at power-on, mid-sweep or not. A
//!   version-2 head sends its `HELLO` unprompted; sweep ids, the reading counter and the ms clock of
//!   `RD` lines start again from 0.
//! - `HELLO,v` → `HELLO,2,sonar-sim <version>,<head_id>,<step_cdeg>,<pings_per_reading>,<min_cdeg>,
//!   <max_cdeg>` if `v` is the version the head speaks, else `ERR,VERSION,…` (`--head-id`, random
//!   by default; version 1 leaves the identity out). A scan under way goes on.
//! - `SCAN,FULL` → `ACK,SCAN`. At a limit, the sweep starts at once, away from it. Between the
//!   limits the head first drives on (no pings) to the limit ahead in its current direction, which
//!   reports `LIM,MIN|MAX` and reverses it. Each sweep is `SWP,START,<id>,<dir>,F,<first>,<last>`
//!   (first and last reading centres in sweep order), one `RD` per reading centre in the order of
//!   motion (50 by default, −147° … +147° in 6°), then the head runs on to the limit switch:
//!   `LIM,…`, `SWP,END,<id>`, and the next sweep (id + 1) starts back. Forever, until `STOP`.
//! - `SCAN,LOCAL,a,b` (centidegrees) → `ERR,RANGE,…` if `a` or `b` lies outside the limits or no
//!   reading centre lies in `[a, b]`; else `ACK,SCAN`, the head drives (no pings) to the end of the
//!   segment nearest to it (the outermost ping position, 2.25° beyond the outermost centre) and
//!   sweeps back and forth over the centres in `[a, b]`: `SWP,START,…,L,…`, the `RD`s, `SWP,END`,
//!   then at once the pass back. No limit switch events.
//! - A `SCAN` during a scan replaces it: `ACK,SCAN`, `SWP,END` for the open sweep, then as above.
//! - `STOP` → `ACK,STOP`, `SWP,END,<id>` if a sweep was open, idle where the head stands. The
//!   reading in progress is discarded.
//! - `STATUS` → `ST,<IDLE|FULL|LOCAL|FAULT>,<angle_cdeg>,<dir>,<sweep>`: the mode (driving to a scan's
//!   start counts as that mode), the head angle, the direction of its last motion, and the open
//!   sweep's id, or the last one (0 before any).
//! - A line with a bad checksum → `ERR,CHECKSUM,…`; any other unreadable line (or one longer than
//!   160 bytes) → `ERR,SYNTAX,…`.
//! - **Hardware faults** (broken switches, `docs/protocol.md`): the model watches the switch ahead
//!   after every half step, as the firmware after every microstep. Both closed, a switch still
//!   open 1.5° past its limit, or one closing more than 1.5° early stops the head:
//!   `ERR,HARDWARE,…`, `SWP,END` of an open sweep, `ST,FAULT,…`; scans are answered with the same
//!   `ERR`, nothing moves until `RESET` (`ACK,RESET`, `SWP,END` if open, `LIM,MIN`: homed at once,
//!   sweep ids go on). Homing being instant, power-on (and a reset) report at once what the
//!   firmware's homing would meet (a dead or stuck MIN switch, both closed); the `ST` angle after
//!   such a homing fault is the MIN limit's, where the firmware reports the angle it assumed.
//! - Commands are obeyed between actions (after the current motor step or ping), as the PIC's main
//!   loop would; a reply comes at most one ping (50 ms simulated) late.
//! - `RD,<seq>,<time_ms>,<sweep>,<dir>,<centre_cdeg>,<P>,<e1>,…,<eP>`: `seq` from 0, +1 per `RD`
//!   for the life of the process; `time_ms` the simulated clock when the last ping's echo came in
//!   (its time of flight after the trigger, or the sensor's time-out without one), when the line is
//!   sent, as the firmware does (`firmware/src/motion.c`, `head_ping_done`); `P` pings
//!   (4), taken at the P stepper positions of the reading, centre + (j − (P−1)/2)·step, in the order
//!   of motion (−2.25°, −0.75°, +0.75°, +2.25° going CCW); echo times in µs, 0 = no echo.
//! - Timing ([`Timing`]): a ping takes 50 ms (echo wait included: the rest of it is waited out
//!   after the reading is sent), a 1.5° step 10 ms. The limit
//!   switches sit half a step beyond the outermost ping positions. A full sweep takes
//!   50 × (4 × 10 + 4 × 50) ms ≈ 12 s.
//!
//! # Echo model
//!
//! See [`echo`] for the physics and [`EchoParams`]/[`NoiseParams`] for every parameter and where
//! its default comes from (`shared/docs/sensor-facts.md`, ISO 9613-1, or the calibration points).
//! In short: a flat wall returns only at normal incidence within the 28° specular cut-off, at the
//! perpendicular distance; concave corners return from anywhere in the ±30° beam; edges weakly; a
//! post from its nearest point with a strength growing with its radius, so a 5 cm post at 1 m is
//! heard only within about ±13° of it. Levels combine spreading, air absorption, the receiver's
//! gain ramp and the beam pattern against one detection threshold; the nearest echo above it
//! wins, unless the line of sight is blocked. Noise: late detection by up to two cycles (≤ 8.6 mm)
//! and 0.5 % transient short readings, from a seeded ChaCha RNG.
//!
//! That is the model without a sensor profile, the calibration behind `docs/results.md`. A
//! [`profile`] (`profile = "hc-sr04"` in a scene file, `--profile`) names a sensor instead:
//! `srf05` (refitted so that a 5 cm post is heard to about 1.1 m), `hc-sr04` (a 15° measuring
//! angle, 60 ms per ping) or `nxt` (processed whole-centimetre ranges 3 cm short, 3° steps), each
//! with per-ping Gaussian range noise, ±1 dB of amplitude jitter, dropouts and double-bounce
//! ghosts, and with its own head geometry and timing. Thin boards (`surface = "board"`) are
//! faint and silent edge-on under any model.
//!
//! # Ground truth
//!
//! [`Scene::walls`], [`Scene::posts`] and [`Scene::distance_to_surface`] give other crates (the
//! evaluation) the true surfaces to rasterise.

pub mod echo;
pub mod echo_params;
pub mod faults;
pub mod firmware;
pub mod geometry;
pub mod hobby;
pub mod link;
pub mod profile;
pub mod robot;
pub mod scene;
pub mod serve;

pub use echo::{Echo, EchoModel, EchoParams, NoiseParams, Target};
pub use faults::{
    FaultCounts, FaultInjector, FaultSpec, LineFault, SpecError, SwitchFault, SwitchFaults,
};
pub use firmware::{FIRMWARE_ID, Firmware, Timing, Transducer};
pub use geometry::{Pose, Vec2};
pub use hobby::HobbySketch;
pub use link::Symlink;
pub use profile::SensorProfile;
pub use robot::{Mode, Odometry, OdometryParams, PoseSample, Robot, RobotSpec, Rover, Trajectory};
pub use scene::{
    BUILTIN_NAMES, Joint, Post, Scene, SceneError, SuggestedScan, Surface, Vertex, Wall,
};
pub use serve::{
    Carrier, Device, NativeDevice, Pty, ServeStats, Speed, SweepCounts, act_carried, report_sweeps,
    serve,
};
#[doc(no_inline)]
pub use sonar_common::protocol::DeviceMessage;
