//! A head fixed at the origin reads exactly as it did before the head could ride a robot: every
//! ping and every first echo (range and level, to the bit) of the built-in fixed-head scenes,
//! aimed every 0.25° round the circle, folded into one digest taken from the code before.

use sonar_common::sensor::SensorConfig;
use sonar_sim::{EchoModel, Scene, Transducer};

/// FNV-1a over the values of the fixed-head code (commit 01f6e9a).
const DIGEST_BEFORE_THE_ROBOT: u64 = 0x9d1b_9f4e_a88a_735e;

#[test]
fn a_fixed_head_reads_exactly_as_before() {
    let mut digest: u64 = 0xcbf2_9ce4_8422_2325;
    let mut fold = |x: u64| digest = (digest ^ x).wrapping_mul(0x100_0000_01b3);
    for name in ["room", "corner", "obstacle", "two-obstacles"] {
        let mut m =
            EchoModel::new(Scene::builtin(name).unwrap(), SensorConfig::default(), 5).unwrap();
        for k in 0..1440 {
            let aim = -180.0 + 0.25 * f64::from(k);
            let first = m.first_echo(aim);
            fold(first.map_or(0, |e| e.range_m.to_bits()));
            fold(first.map_or(0, |e| e.margin_db.to_bits()));
            fold(m.echoes(aim).len() as u64);
            fold(u64::from(m.ping(aim)));
        }
    }
    println!("digest {digest:#x}");
    assert_eq!(digest, DIGEST_BEFORE_THE_ROBOT);
}
