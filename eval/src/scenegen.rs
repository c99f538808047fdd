//! Generated scenes for the suite ([`crate::suite`]): rooms and corridors with inner partitions,
//! doorways, thin boards, posts of 2–10 cm and furniture legs, each with eight viewpoints in its
//! free space, all drawn from one seed.
//!
//! A scene is built in its own frame, then turned by a random angle (so walls do not line up with
//! the grid's axes) and kept within ±3.6 m of the origin, inside the fusion grid's ±4 m:
//!
//! - **room** (half the scenes): 2.4–4.6 m by 2.4–4.6 m; each outer wall has a 0.8–0.9 m doorway with
//!   probability 0.3 (nothing beyond it: pings through it hear nothing); one corner cut at 45°
//!   (0.4–0.8 m) with probability 0.3, which makes two 135° corners; an inner partition with
//!   probability 0.7, either a wall from one side across 40–70 % of the room or a wall across all
//!   of it with a 0.85 m doorway;
//! - **corridor**: 1.2–1.8 m wide, 5–5.6 m long, one or two doorways in its sides, each opening
//!   onto a small room (three walls, 1–1.2 m deep) beyond.
//!
//! Then, inside the room or corridor, away from every surface: 0–2 thin boards
//! ([`Surface::Board`], 0.4–1.2 m, any orientation), 0–3 posts of 2–10 cm diameter, and with
//! probability 0.5 a table's four legs (2–4 cm, at the corners of a 0.5–1.2 m by 0.5–0.8 m
//! rectangle). The **viewpoints** are eight poses drawn uniformly inside the room or corridor at
//! least 0.35 m from every surface, each with a uniform heading; the suite uses the first 1, 3
//! and 8, so the sets are nested.
//!
//! The **arenas** ([`Family::Arenas`]) are another family, after the only recorded scans the
//! project was measured on that it did not write (issue 23: a rotating ultrasonic sensor at five
//! known places inside a 2.1 m arena of eight boards): a square of four thin boards
//! ([`Surface::Board`], 1.9–2.3 m a side, meeting at the corners) with two to four inner boards
//! (0.3–0.8 m, any orientation) and nothing else; everything answers 8 dB less than a wall and
//! nothing edge-on, so the beams of one place pass beside and along the boards another place
//! hears. Eight viewpoints as above; the recorded scans had five (`--suite-viewpoints 1,3,5`).

use anyhow::{Result, bail};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sonar_sim::geometry::{rotate, segments_intersect};
use sonar_sim::scene::distance_to_surfaces;
use sonar_sim::{Pose, Post, Scene, Surface, Vec2, Wall};

/// Viewpoints drawn per scene.
pub const VIEWPOINTS: usize = 8;
/// A viewpoint keeps this far from every surface (a small robot's radius).
pub const VIEWPOINT_CLEARANCE_M: f64 = 0.35;
/// Boards, posts and legs keep this far from every other surface.
const CLEARANCE_M: f64 = 0.15;
/// Every wall stays within this of the origin (the fusion grid reaches ±4 m).
const EXTENT_M: f64 = 3.6;

/// The layouts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    Room,
    Corridor,
    Arena,
}

/// Which scenes the generator draws from a seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Family {
    /// Rooms and corridors of hard walls, with partitions, doorways, thin boards, posts and table
    /// legs (half each).
    #[default]
    Rooms,
    /// Small square arenas of thin boards with inner boards, after the recorded scans of issue
    /// 23.
    Arenas,
}

/// An arena's side, metres (the recorded one: 2.1 m).
const ARENA_SIDE_M: std::ops::RangeInclusive<f64> = 1.9..=2.3;
/// Inner boards of an arena (the recorded one had eight boards in all).
const ARENA_INNER_BOARDS: std::ops::RangeInclusive<usize> = 2..=4;
/// An arena's inner boards' lengths, metres.
const ARENA_BOARD_M: std::ops::RangeInclusive<f64> = 0.3..=0.8;

/// A generated scene: geometry in the world frame and the viewpoints to scan it from.
#[derive(Debug, Clone)]
pub struct Generated {
    /// The scene, named `gen-<seed>`, with the default echo and noise (the suite sets a profile
    /// on each view of it).
    pub scene: Scene,
    pub layout: Layout,
    /// [`VIEWPOINTS`] poses in free space.
    pub viewpoints: Vec<Pose>,
}

/// An axis-aligned free rectangle in the scene's own frame: where things and viewpoints go.
#[derive(Debug, Clone, Copy)]
struct Area {
    lo: Vec2,
    hi: Vec2,
}

impl Area {
    fn sample(&self, rng: &mut ChaCha8Rng) -> Vec2 {
        Vec2::new(
            rng.random_range(self.lo.x..=self.hi.x),
            rng.random_range(self.lo.y..=self.hi.y),
        )
    }
}

struct Builder {
    rng: ChaCha8Rng,
    walls: Vec<Wall>,
    posts: Vec<Post>,
}

impl Builder {
    fn wall(&mut self, a: [f64; 2], b: [f64; 2]) {
        self.walls.push(Wall {
            a: a.into(),
            b: b.into(),
            surface: Surface::Hard,
        });
    }

    /// A wall from `a` to `b` with a doorway of `width` centred at `t` (0–1) along it.
    fn wall_with_door(&mut self, a: Vec2, b: Vec2, t: f64, width: f64) {
        let len = (b - a).norm();
        let dir = (b - a) * (1.0 / len);
        let mid = len * t;
        let (d0, d1) = (mid - width / 2.0, mid + width / 2.0);
        self.walls.push(Wall {
            a,
            b: a + dir * d0,
            surface: Surface::Hard,
        });
        self.walls.push(Wall {
            a: a + dir * d1,
            b,
            surface: Surface::Hard,
        });
    }

    fn distance_to_surface(&self, p: Vec2) -> f64 {
        distance_to_surfaces(&self.walls, &self.posts, p)
    }

    /// A board of random length (within `lengths`) and orientation somewhere in `area`, clear
    /// of everything.
    fn board(&mut self, area: Area, lengths: std::ops::RangeInclusive<f64>) {
        for _ in 0..50 {
            let centre = area.sample(&mut self.rng);
            let len = self.rng.random_range(lengths.clone());
            let half = rotate(
                Vec2::new(len / 2.0, 0.0),
                self.rng.random_range(0.0..std::f64::consts::PI),
            );
            let (a, b) = (centre - half, centre + half);
            let clear = (0..=10).all(|k| {
                let p = a + (b - a) * (f64::from(k) / 10.0);
                self.distance_to_surface(p) >= CLEARANCE_M
            }) && !self
                .walls
                .iter()
                .any(|w| segments_intersect(a, b, w.a, w.b));
            if clear {
                self.walls.push(Wall {
                    a,
                    b,
                    surface: Surface::Board,
                });
                return;
            }
        }
    }

    /// A post of `radius` at `centre` if it is clear of everything (and of the origin, where a
    /// scene without a robot would put its sensor).
    fn try_post(&mut self, centre: Vec2, radius: f64) -> bool {
        let clear = self.distance_to_surface(centre) >= radius + CLEARANCE_M
            && centre.norm() > radius + 0.01;
        if clear {
            self.posts.push(Post {
                centre,
                radius,
                surface: Surface::Hard,
            });
        }
        clear
    }

    fn post(&mut self, area: Area) {
        for _ in 0..50 {
            let centre = area.sample(&mut self.rng);
            let radius = self.rng.random_range(0.01..=0.05);
            if self.try_post(centre, radius) {
                return;
            }
        }
    }

    /// A table's four legs.
    fn table(&mut self, area: Area) {
        for _ in 0..50 {
            let centre = area.sample(&mut self.rng);
            let (w, d) = (
                self.rng.random_range(0.5..=1.2),
                self.rng.random_range(0.5..=0.8),
            );
            let turn = self.rng.random_range(0.0..std::f64::consts::PI);
            let radius = self.rng.random_range(0.01..=0.02);
            let legs: Vec<Vec2> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                .iter()
                .map(|&(sx, sy)| centre + rotate(Vec2::new(sx * w / 2.0, sy * d / 2.0), turn))
                .collect();
            let before = self.posts.len();
            if legs.iter().all(|&p| self.try_post(p, radius)) {
                return;
            }
            self.posts.truncate(before);
        }
    }
}

/// The scene of `seed` among the rooms and corridors.
pub fn generate(seed: u64) -> Result<Generated> {
    generate_in(Family::Rooms, seed)
}

/// The scene of `seed` in `family`.
pub fn generate_in(family: Family, seed: u64) -> Result<Generated> {
    let mut b = Builder {
        rng: ChaCha8Rng::seed_from_u64(seed),
        walls: Vec::new(),
        posts: Vec::new(),
    };
    let layout = match family {
        Family::Arenas => Layout::Arena,
        Family::Rooms if b.rng.random_bool(0.5) => Layout::Room,
        Family::Rooms => Layout::Corridor,
    };
    let area = match layout {
        Layout::Room => room(&mut b),
        Layout::Corridor => corridor(&mut b),
        Layout::Arena => arena(&mut b),
    };
    if layout == Layout::Arena {
        for _ in 0..b.rng.random_range(ARENA_INNER_BOARDS) {
            b.board(area, ARENA_BOARD_M);
        }
    } else {
        for _ in 0..b.rng.random_range(0..=2) {
            b.board(area, 0.4..=1.2);
        }
        for _ in 0..b.rng.random_range(0..=3) {
            b.post(area);
        }
        if b.rng.random_bool(0.5) {
            b.table(area);
        }
    }
    let mut viewpoints = Vec::new();
    for _ in 0..10_000 {
        if viewpoints.len() == VIEWPOINTS {
            break;
        }
        let at = area.sample(&mut b.rng);
        let heading = b
            .rng
            .random_range(-std::f64::consts::PI..std::f64::consts::PI);
        if b.distance_to_surface(at) >= VIEWPOINT_CLEARANCE_M {
            viewpoints.push(Pose {
                at,
                heading_rad: heading,
            });
        }
    }
    if viewpoints.len() < VIEWPOINTS {
        bail!("scene {seed}: no room for {VIEWPOINTS} viewpoints");
    }
    // Turned as a whole, so that walls do not line up with the grid.
    let turn = b.rng.random_range(0.0..std::f64::consts::FRAC_PI_2);
    let walls = b
        .walls
        .iter()
        .map(|w| Wall {
            a: rotate(w.a, turn),
            b: rotate(w.b, turn),
            surface: w.surface,
        })
        .collect();
    let posts = b
        .posts
        .iter()
        .map(|p| Post {
            centre: rotate(p.centre, turn),
            ..*p
        })
        .collect();
    let viewpoints = viewpoints
        .into_iter()
        .map(|v| Pose {
            at: rotate(v.at, turn),
            heading_rad: v.heading_rad + turn,
        })
        .collect();
    let prefix = match family {
        Family::Rooms => "gen",
        Family::Arenas => "arena",
    };
    let mut scene = Scene::new(&format!("{prefix}-{seed}"), walls, posts)?;
    scene.description = format!("generated {layout:?} (seed {seed})").to_lowercase();
    Ok(Generated {
        scene,
        layout,
        viewpoints,
    })
}

/// Salt of the draw of rough walls, so that it leaves the scene's own draws as they were.
const ROUGH_SALT: u64 = 0x726f_7567_6800_0000;

/// `scene` with about `share` of its hard walls rough ([`Surface::Rough`]: brick, a full
/// bookshelf, ribbed panels, which scatter sound back from wherever they are met), each drawn
/// from `seed` on its own (salted, so that no draw of the scene's own repeats): the geometry, the
/// robot and every other wall as they were.
pub fn with_rough_walls(scene: &Scene, share: f64, seed: u64) -> Result<Scene> {
    if !(0.0..=1.0).contains(&share) {
        bail!("a share of rough walls must lie in 0..=1, not {share}");
    }
    if share == 0.0 {
        return Ok(scene.clone());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ ROUGH_SALT);
    let mut rough = scene.with_surfaces(|w| {
        if rng.random_bool(share) && w.surface == Surface::Hard {
            Surface::Rough
        } else {
            w.surface
        }
    })?;
    rough.description = format!("{}, {share} of its walls rough", scene.description);
    Ok(rough)
}

impl Generated {
    /// The same scene with about `share` of its hard walls rough ([`with_rough_walls`]), drawn
    /// from `seed`; the viewpoints as they were.
    pub fn with_rough_walls(self, share: f64, seed: u64) -> Result<Self> {
        Ok(Self {
            scene: with_rough_walls(&self.scene, share, seed)?,
            ..self
        })
    }
}

/// A room; returns its inside, less the clearance.
fn room(b: &mut Builder) -> Area {
    let (w, h): (f64, f64) = (b.rng.random_range(2.4..=4.6), b.rng.random_range(2.4..=4.6));
    // Off centre by up to 0.5 m, every corner within the extent.
    let slack = (EXTENT_M - (w / 2.0).hypot(h / 2.0)).clamp(0.0, 0.5) / std::f64::consts::SQRT_2;
    let c = Vec2::new(
        b.rng.random_range(-slack..=slack),
        b.rng.random_range(-slack..=slack),
    );
    let (x0, x1, y0, y1) = (c.x - w / 2.0, c.x + w / 2.0, c.y - h / 2.0, c.y + h / 2.0);
    // Corners counter-clockwise; one may be cut at 45°.
    let cut = b
        .rng
        .random_bool(0.3)
        .then(|| (b.rng.random_range(0..4usize), b.rng.random_range(0.4..=0.8)));
    let corners = [
        Vec2::new(x0, y0),
        Vec2::new(x1, y0),
        Vec2::new(x1, y1),
        Vec2::new(x0, y1),
    ];
    let mut outline: Vec<Vec2> = Vec::new();
    for (k, &p) in corners.iter().enumerate() {
        match cut {
            Some((ck, size)) if ck == k => {
                let prev = corners[(k + 3) % 4];
                let next = corners[(k + 1) % 4];
                outline.push(p + (prev - p) * (size / (prev - p).norm()));
                outline.push(p + (next - p) * (size / (next - p).norm()));
            }
            _ => outline.push(p),
        }
    }
    let n = outline.len();
    for k in 0..n {
        let (a, e) = (outline[k], outline[(k + 1) % n]);
        let len = (e - a).norm();
        if len > 1.6 && b.rng.random_bool(0.3) {
            let width = b.rng.random_range(0.8..=0.9);
            let margin = (0.3 + width / 2.0) / len;
            let t = b.rng.random_range(margin..=1.0 - margin);
            b.wall_with_door(a, e, t, width);
        } else {
            b.walls.push(Wall {
                a,
                b: e,
                surface: Surface::Hard,
            });
        }
    }
    if b.rng.random_bool(0.7) {
        // Across the longer side, away from the walls.
        let along_x = w >= h;
        let (lo, hi) = if along_x { (x0, x1) } else { (y0, y1) };
        let at = b.rng.random_range(lo + 0.9..=hi - 0.9);
        let (s0, s1) = if along_x { (y0, y1) } else { (x0, x1) };
        let point = |s: f64| if along_x { [at, s] } else { [s, at] };
        if b.rng.random_bool(0.5) {
            // From one side, 40–70 % of the way across.
            let reach = (s1 - s0) * b.rng.random_range(0.4..=0.7);
            if b.rng.random_bool(0.5) {
                b.wall(point(s0), point(s0 + reach));
            } else {
                b.wall(point(s1 - reach), point(s1));
            }
        } else {
            let width = 0.85;
            let margin = (0.3 + width / 2.0) / (s1 - s0);
            let t = b.rng.random_range(margin..=1.0 - margin);
            b.wall_with_door(point(s0).into(), point(s1).into(), t, width);
        }
    }
    let m = 0.05;
    Area {
        lo: Vec2::new(x0 + m, y0 + m),
        hi: Vec2::new(x1 - m, y1 - m),
    }
}

/// A square of four thin boards meeting at its corners, centred off the origin by up to 0.3 m;
/// returns its inside.
fn arena(b: &mut Builder) -> Area {
    let side = b.rng.random_range(ARENA_SIDE_M);
    let c = Vec2::new(
        b.rng.random_range(-0.3..=0.3),
        b.rng.random_range(-0.3..=0.3),
    );
    let h = side / 2.0;
    let corners = [
        Vec2::new(c.x - h, c.y - h),
        Vec2::new(c.x + h, c.y - h),
        Vec2::new(c.x + h, c.y + h),
        Vec2::new(c.x - h, c.y + h),
    ];
    for k in 0..4 {
        b.walls.push(Wall {
            a: corners[k],
            b: corners[(k + 1) % 4],
            surface: Surface::Board,
        });
    }
    let m = 0.05;
    Area {
        lo: Vec2::new(c.x - h + m, c.y - h + m),
        hi: Vec2::new(c.x + h - m, c.y + h - m),
    }
}

/// A corridor along x, with side rooms through its doorways; returns the corridor's inside.
fn corridor(b: &mut Builder) -> Area {
    let width = b.rng.random_range(1.2..=1.8);
    let length = b.rng.random_range(5.0..=5.6);
    let (x0, x1) = (-length / 2.0, length / 2.0);
    let (y0, y1) = (-width / 2.0, width / 2.0);
    b.wall([x0, y0], [x0, y1]);
    b.wall([x1, y0], [x1, y1]);
    let doors = b.rng.random_range(1..=2);
    // Which sides get a door (and where): one per side at most.
    let mut sides = [None, None];
    for d in 0..doors {
        let side = if doors == 2 {
            d
        } else {
            b.rng.random_range(0..2usize)
        };
        let door_w = b.rng.random_range(0.8..=0.9);
        let centre = b.rng.random_range(x0 + 1.2..=x1 - 1.2);
        sides[side] = Some((centre, door_w));
    }
    for (side, y, out) in [(0, y0, -1.0), (1, y1, 1.0)] {
        match sides[side] {
            Some((centre, door_w)) => {
                let t = (centre - x0) / length;
                b.wall_with_door(Vec2::new(x0, y), Vec2::new(x1, y), t, door_w);
                // The room beyond: three walls from the corridor's wall, 1–1.5 m deep.
                let depth = b.rng.random_range(1.0..=1.2);
                let half = b.rng.random_range(0.8..=1.2);
                let (l, r) = ((centre - half).max(x0), (centre + half).min(x1));
                let far = y + out * depth;
                b.wall([l, y], [l, far]);
                b.wall([l, far], [r, far]);
                b.wall([r, far], [r, y]);
            }
            None => b.wall([x0, y], [x1, y]),
        }
    }
    let m = 0.05;
    Area {
        lo: Vec2::new(x0 + m, y0 + m),
        hi: Vec2::new(x1 - m, y1 - m),
    }
}

/// `scene` seen from `pose`: every wall and post moved into the frame where the sensor stands at
/// the origin facing +x, so that the pipeline's fixed head scans it from there. Echo and noise are
/// the scene's.
pub fn seen_from(scene: &Scene, pose: Pose) -> Result<Scene> {
    Ok(scene.moved(&scene.name, |p| rotate(p - pose.at, -pose.heading_rad))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rough_walls_are_drawn_from_their_own_seed_and_change_nothing_else() {
        let smooth = generate_in(Family::Rooms, 7).unwrap();
        let rough = smooth.clone().with_rough_walls(0.5, 7).unwrap();
        let (a, b) = (smooth.scene.walls(), rough.scene.walls());
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert_eq!((x.a, x.b), (y.a, y.b));
            match x.surface {
                Surface::Hard => assert!(matches!(y.surface, Surface::Hard | Surface::Rough)),
                other => assert_eq!(y.surface, other),
            }
        }
        assert!(b.iter().any(|w| w.surface == Surface::Rough));
        assert!(b.iter().any(|w| w.surface == Surface::Hard));
        assert_eq!(smooth.viewpoints, rough.viewpoints);
        let all = smooth.clone().with_rough_walls(1.0, 7).unwrap();
        assert!(all.scene.walls().iter().all(|w| w.surface != Surface::Hard));
        assert!(smooth.clone().with_rough_walls(1.5, 7).is_err());
        assert_eq!(
            smooth
                .clone()
                .with_rough_walls(0.0, 7)
                .unwrap()
                .scene
                .walls(),
            smooth.scene.walls()
        );
    }
    use sonar_sim::geometry::distance_to_segment;

    #[test]
    fn scenes_repeat_by_seed_and_hold_what_the_suite_needs() {
        let mut layouts = [0, 0];
        let (mut boards, mut posts) = (0, 0);
        for seed in 0..40 {
            let g = generate(seed).unwrap();
            let again = generate(seed).unwrap();
            assert_eq!(g.scene.walls(), again.scene.walls());
            assert_eq!(g.viewpoints, again.viewpoints);
            layouts[g.layout as usize] += 1;
            boards += g
                .scene
                .walls()
                .iter()
                .filter(|w| w.surface == Surface::Board)
                .count();
            for p in g.scene.posts() {
                assert!((0.01..=0.05).contains(&p.radius));
                posts += 1;
            }
            assert_eq!(g.viewpoints.len(), VIEWPOINTS);
            for v in &g.viewpoints {
                assert!(g.scene.distance_to_surface(v.at) >= VIEWPOINT_CLEARANCE_M - 1e-9);
            }
            for w in g.scene.walls() {
                assert!(
                    w.a.norm() < EXTENT_M && w.b.norm() < EXTENT_M,
                    "{seed}: {w:?}"
                );
            }
        }
        assert!(layouts[0] > 5 && layouts[1] > 5, "{layouts:?}");
        assert!(boards > 10 && posts > 20, "{boards} boards, {posts} posts");
        assert_ne!(
            generate(1).unwrap().scene.walls(),
            generate(2).unwrap().scene.walls()
        );
    }

    #[test]
    fn arenas_are_squares_of_boards_with_inner_boards_and_room_for_every_viewpoint() {
        let mut inner_boards = 0;
        for seed in 0..40 {
            let g = generate_in(Family::Arenas, seed).unwrap();
            assert_eq!(g.layout, Layout::Arena);
            assert_eq!(g.scene.name, format!("arena-{seed}"));
            assert_eq!(
                g.scene.walls(),
                generate_in(Family::Arenas, seed).unwrap().scene.walls()
            );
            let walls = g.scene.walls();
            assert!(walls.iter().all(|w| w.surface == Surface::Board), "{seed}");
            assert!(g.scene.posts().is_empty(), "{seed}");
            // Four sides of one length meeting end to end, then the inner boards.
            let side = (walls[0].b - walls[0].a).norm();
            assert!(ARENA_SIDE_M.contains(&side), "{seed}: side {side}");
            for k in 0..4 {
                assert!(((walls[k].b - walls[k].a).norm() - side).abs() < 1e-9);
                assert!((walls[k].b - walls[(k + 1) % 4].a).norm() < 1e-9);
            }
            let inner = walls.len() - 4;
            assert!(
                inner <= *ARENA_INNER_BOARDS.end(),
                "{seed}: {inner} inner boards"
            );
            inner_boards += inner;
            for w in &walls[4..] {
                assert!(ARENA_BOARD_M.contains(&(w.b - w.a).norm()), "{seed}: {w:?}");
            }
            assert_eq!(g.viewpoints.len(), VIEWPOINTS);
            for v in &g.viewpoints {
                assert!(g.scene.distance_to_surface(v.at) >= VIEWPOINT_CLEARANCE_M - 1e-9);
            }
        }
        assert!(
            inner_boards >= 2 * 40,
            "{inner_boards} inner boards in 40 arenas"
        );
        // The rooms' family is what it was.
        assert_eq!(
            generate(5).unwrap().scene.walls(),
            generate_in(Family::Rooms, 5).unwrap().scene.walls()
        );
    }

    #[test]
    fn a_scene_seen_from_a_pose_puts_that_pose_at_the_origin() {
        let g = generate(3).unwrap();
        let v = g.viewpoints[0];
        let seen = seen_from(&g.scene, v).unwrap();
        for (w, s) in g.scene.walls().iter().zip(seen.walls()) {
            let d_world = distance_to_segment(w.a, w.b, v.at);
            let d_seen = distance_to_segment(s.a, s.b, Vec2::default());
            assert!((d_world - d_seen).abs() < 1e-9);
        }
        // What lies ahead of the pose lies on +x.
        let ahead = v.at + rotate(Vec2::new(1.0, 0.0), v.heading_rad);
        let p = rotate(ahead - v.at, -v.heading_rad);
        assert!((p - Vec2::new(1.0, 0.0)).norm() < 1e-12);
    }
}
