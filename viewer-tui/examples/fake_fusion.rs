//! A stand-in for the fusion engine (and, with `--driver`, for the driver's status), to try the
//! viewer without the rest of the pipeline: a sensor at the origin of a 4.5 m × 3 m room with a post
//! sweeps back and forth, and the room appears in `sonar/grid` and `sonar/radar` sweep by sweep.
//!
//! It publishes on the real services with the real types, so the viewer cannot tell the
//! difference; the map it builds is a cartoon (free along each ray, occupied at the hit), not the
//! fusion engine's sensor model.
//!
//!     cargo run -p sonar-viewer --example fake_fusion -- --driver &
//!     cargo run -p sonar-viewer
//!
//! Keys of the viewer it reacts to: `C` clears, `m`/`r`/`p` change the reported settings, and with
//! `--driver` also `f`, `l` (the sweep turns between the segment's ends) and `x`.

use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use clap::Parser;
use sonar_common::ipc::{
    self, CELL_UNKNOWN, DriverStatus, FusionCommandKind, GridHeader, IpcArgs, LAYOUT_VERSION,
    LinkState, Radar, ScanCommandKind, ScanMode, encode_probability, model_code, preset_code,
    rule_code,
};

#[derive(Debug, Parser)]
struct Args {
    /// Also publish the driver's status and obey scan commands (do not run a real driver then).
    #[arg(long)]
    driver: bool,
    /// Grid side in cells (2 cm each).
    #[arg(long, default_value_t = 400)]
    size: u32,
    /// Sweep speed, degrees per second.
    #[arg(long, default_value_t = 60.0)]
    speed: f32,
    #[command(flatten)]
    ipc: IpcArgs,
}

const RESOLUTION_M: f32 = 0.02;
const MAX_RANGE_M: f32 = 4.0;
const STEP_DEG: f32 = 6.0;
const TICK: Duration = Duration::from_millis(50);

/// Range from the origin along `deg` to the room's walls or the post, if within `MAX_RANGE_M`.
fn range(deg: f32) -> Option<f32> {
    let (dy, dx) = deg.to_radians().sin_cos();
    // Inside the room (-2.5..2) × (-1.5..1.5): the nearest wall ahead.
    let wall = |lo: f32, hi: f32, d: f32| {
        if d > 0.0 {
            hi / d
        } else if d < 0.0 {
            lo / d
        } else {
            f32::INFINITY
        }
    };
    let mut r = wall(-2.5, 2.0, dx).min(wall(-1.5, 1.5, dy));
    // The post (0.8..1.1) × (0.4..0.7): slab test.
    let slab = |lo: f32, hi: f32, d: f32| {
        if d == 0.0 {
            if lo <= 0.0 && 0.0 <= hi {
                (f32::NEG_INFINITY, f32::INFINITY)
            } else {
                (f32::INFINITY, f32::NEG_INFINITY)
            }
        } else {
            let (a, b) = (lo / d, hi / d);
            (a.min(b), a.max(b))
        }
    };
    let (x0, x1) = slab(0.8, 1.1, dx);
    let (y0, y1) = slab(0.4, 0.7, dy);
    let (enter, exit) = (x0.max(y0), x1.min(y1));
    if enter <= exit && enter > 0.0 {
        r = r.min(enter);
    }
    (r <= MAX_RANGE_M).then_some(r)
}

struct World {
    side: u32,
    /// Occupancy probability per cell, NaN = never observed.
    p: Vec<f32>,
    radar: Radar,
    header: GridHeader,
}

impl World {
    fn new(side: u32) -> Self {
        let mut w = Self {
            side,
            p: Vec::new(),
            radar: Radar::default(),
            header: GridHeader {
                layout_version: LAYOUT_VERSION,
                width: side,
                height: side,
                resolution_m: RESOLUTION_M,
                origin_x_m: -(side as f32) * RESOLUTION_M / 2.0,
                origin_y_m: -(side as f32) * RESOLUTION_M / 2.0,
                model: model_code::PAPER,
                rule: rule_code::BAYES,
                preset: preset_code::PAPER,
                ..GridHeader::default()
            },
        };
        w.clear();
        w
    }

    fn clear(&mut self) {
        self.p = vec![f32::NAN; (self.side * self.side) as usize];
        self.header.readings_fused = 0;
        self.radar = Radar {
            bin_count: (300.0 / STEP_DEG) as u32,
            first_bin_deg: -150.0 + STEP_DEG / 2.0,
            bin_width_deg: STEP_DEG,
            beam_half_angle_deg: 30.0,
            max_range_m: MAX_RANGE_M,
            ..Radar::default()
        };
    }

    fn update(&mut self, x_m: f32, y_m: f32, f: impl Fn(f32) -> f32) {
        let h = &self.header;
        let (x, y) = (
            (x_m - h.origin_x_m) / h.resolution_m,
            (y_m - h.origin_y_m) / h.resolution_m,
        );
        if x >= 0.0 && y >= 0.0 && x < self.side as f32 && y < self.side as f32 {
            let i = y as usize * self.side as usize + x as usize;
            let prior = if self.p[i].is_nan() { 0.5 } else { self.p[i] };
            self.p[i] = f(prior);
        }
    }

    /// One reading centred on `deg`: rays over ±12°, free up to the hit, occupied at it.
    fn fuse(&mut self, deg: f32) {
        let bin = ((deg - self.radar.first_bin_deg) / STEP_DEG).round();
        if bin >= 0.0 && (bin as u32) < self.radar.bin_count {
            self.radar.distances_m[bin as usize] = range(deg).unwrap_or(f32::INFINITY);
        }
        let mut a = deg - 12.0;
        while a <= deg + 12.0 {
            let hit = range(a);
            let (dy, dx) = a.to_radians().sin_cos();
            let mut r = 0.0;
            while r < hit.unwrap_or(MAX_RANGE_M) - RESOLUTION_M {
                self.update(r * dx, r * dy, |p| p * 0.8);
                r += RESOLUTION_M / 2.0;
            }
            if let Some(hit) = hit {
                self.update((hit + 0.01) * dx, (hit + 0.01) * dy, |p| {
                    1.0 - (1.0 - p) * 0.5
                });
            }
            a += 0.5;
        }
        self.header.readings_fused += 1;
    }

    fn cells(&mut self) -> Vec<u8> {
        let cells: Vec<u8> = self
            .p
            .iter()
            .map(|&p| {
                if p.is_nan() {
                    CELL_UNKNOWN
                } else {
                    encode_probability(p)
                }
            })
            .collect();
        let h = &mut self.header;
        h.occupied_cells = cells
            .iter()
            .filter(|&&c| c != CELL_UNKNOWN && c > 127)
            .count() as u32;
        h.free_cells = cells.iter().filter(|&&c| c < 127).count() as u32;
        h.unknown_cells = cells.iter().filter(|&&c| c == CELL_UNKNOWN).count() as u32;
        h.seq += 1;
        h.stamp_ns = ipc::unix_time_ns();
        cells
    }
}

fn main() -> Result<()> {
    let args = Args::parse();
    let err = |what: &'static str| move |e: &dyn std::fmt::Debug| anyhow!("{what}: {e:?}");
    let node = args.ipc.node("fake-fusion")?;
    let n = (args.size * args.size) as usize;
    let grid = ipc::grid_service(&node)?
        .publisher_builder()
        .initial_max_slice_len(n)
        .create()
        .map_err(|e| err("grid publisher")(&e))?;
    let radar = ipc::radar_service(&node)?
        .publisher_builder()
        .create()
        .map_err(|e| err("radar publisher")(&e))?;
    let fusion_commands = ipc::fusion_commands_service(&node)?
        .subscriber_builder()
        .create()
        .map_err(|e| err("fusion command subscriber")(&e))?;
    let driver = if args.driver {
        let status = ipc::driver_status_service(&node)?
            .publisher_builder()
            .create()
            .map_err(|e| err("status publisher")(&e))?;
        let commands = ipc::commands_service(&node)?
            .subscriber_builder()
            .create()
            .map_err(|e| err("command subscriber")(&e))?;
        Some((status, commands))
    } else {
        None
    };

    let mut world = World::new(args.size);
    let (mut angle, mut direction, mut sweep) = (-150.0f32, 1i32, 0u32);
    let (mut lo, mut hi, mut mode) = (-150.0f32, 150.0f32, ScanMode::Full);
    let mut next_reading = angle;
    let mut status = DriverStatus {
        layout_version: LAYOUT_VERSION,
        link_state: LinkState::Connected as u32,
        ..DriverStatus::default()
    };
    let mut next_status = Instant::now();
    while node.wait(TICK).is_ok() {
        while let Ok(Some(cmd)) = fusion_commands.receive() {
            let cmd = *cmd.payload();
            println!("fusion command {cmd:?}");
            match cmd.kind() {
                Some(FusionCommandKind::Clear) => world.clear(),
                Some(FusionCommandKind::SetModel) => {
                    (world.header.model, world.header.preset) = (cmd.value, preset_code::CUSTOM)
                }
                Some(FusionCommandKind::SetRule) => {
                    (world.header.rule, world.header.preset) = (cmd.value, preset_code::CUSTOM)
                }
                Some(FusionCommandKind::SetPreset) => world.header.preset = cmd.value,
                None => {}
            }
        }
        if let Some((_, commands)) = &driver {
            while let Ok(Some(cmd)) = commands.receive() {
                let cmd = *cmd.payload();
                println!("scan command {cmd:?}");
                (lo, hi, mode) = match cmd.kind() {
                    Some(ScanCommandKind::FullScan) => (-150.0, 150.0, ScanMode::Full),
                    Some(ScanCommandKind::LocalScan) => (cmd.from_deg, cmd.to_deg, ScanMode::Local),
                    Some(ScanCommandKind::Stop) => (lo, hi, ScanMode::Idle),
                    _ => (lo, hi, mode),
                };
                angle = angle.clamp(lo, hi);
                next_reading = angle;
            }
        }
        if mode != ScanMode::Idle {
            angle += direction as f32 * args.speed * TICK.as_secs_f32();
            if angle >= hi || angle <= lo {
                angle = angle.clamp(lo, hi);
                direction = -direction;
                sweep += 1;
                next_reading = angle;
            }
            while (next_reading - angle) * direction as f32 <= 0.0 {
                world.fuse(next_reading);
                status.readings_published += 1;
                status.lines_ok += 1;
                next_reading += direction as f32 * STEP_DEG;
            }
            world.radar.current_angle_deg = angle;
            world.radar.direction = direction;
            world.radar.sweep_id = sweep;
            world.radar.mode = mode as u32;
            world.header.sweep_id = sweep;
        }

        let cells = world.cells();
        let mut sample = grid
            .loan_slice_uninit(n)
            .map_err(|e| err("loan grid")(&e))?;
        *sample.user_header_mut() = world.header;
        let sample = sample.write_from_fn(|i| cells[i]);
        sample.send().map_err(|e| err("send grid")(&e))?;
        world.radar.seq += 1;
        radar
            .send_copy(world.radar)
            .map_err(|e| err("send radar")(&e))?;

        if let Some((publisher, _)) = &driver {
            status.mode = mode as u32;
            status.sweep_id = sweep;
            status.angle_deg = angle;
            status.direction = direction;
            if Instant::now() >= next_status {
                status.stamp_ns = ipc::unix_time_ns();
                publisher
                    .send_copy(status)
                    .map_err(|e| err("send status")(&e))?;
                next_status = Instant::now() + Duration::from_secs(1);
            }
        }
    }
    Ok(())
}
