//! The reference kernel, literally after the paper (§III.B.2): a pass over the whole grid per
//! reading, with its arrays.
//!
//! - GridAngles {a_ij}: each cell's bearing from the sensor, against the reference direction
//!   (the world x axis); filled once, refilled only if the sensor moves.
//! - GridLength {r_ij}: each cell's distance from the sensor ("the center grid element"); likewise.
//! - AngleInside {u_ij}: 1 where the cell lies within the beam width of the current reading,
//!   |α_ij| ≤ β with α_ij = a_ij − θ_k (taken modulo a turn); overwritten for every reading.
//!
//! Then every cell with u_ij = 1 takes the model's evidence and the rule's combination. Slow by
//! design — it is the yardstick the fast kernel ([`crate::kernel`]) is tested and benchmarked
//! against.

use crate::geometry::{GridGeometry, SensorCell, off_axis};
use crate::grid::Layer;
use crate::kernel::{cell_evidence, heard_cell_evidence};
use crate::model::CellEvidence;
use crate::observation::Beam;
use crate::rule::Combine;

/// The paper's arrays, for the sensor position they were filled for.
#[derive(Default)]
pub(crate) struct PaperArrays {
    sensor: Option<SensorCell>,
    grid_angles: Vec<f32>,
    grid_length: Vec<f32>,
    angle_inside: Vec<u8>,
}

impl PaperArrays {
    /// Fuses the reading of `beam` into `layer` and, if the model hears, into `heard` (one bearing
    /// per cell; empty otherwise); returns how many cells it updated.
    pub fn update<R: Combine, E: CellEvidence>(
        &mut self,
        layer: &mut Layer<R>,
        heard: &mut [f32],
        geometry: &GridGeometry,
        beam: &Beam,
        evidence: &E,
    ) -> usize {
        let sensor = geometry.sensor_cell(beam.position);
        if self.sensor != Some(sensor) {
            self.fill(geometry, sensor);
        }
        let cone = layer.rule.cone_half_angle(beam.half_angle);
        for (u, &a) in self.angle_inside.iter_mut().zip(&self.grid_angles) {
            *u = u8::from(off_axis(a, beam.axis).abs() <= cone);
        }
        layer.update_all(|rule, cells| {
            let mut updated = 0;
            for (i, cell) in cells.iter_mut().enumerate() {
                if self.angle_inside[i] == 1 {
                    let (r, a) = (self.grid_length[i], self.grid_angles[i]);
                    let e = if E::HEARD {
                        heard_cell_evidence::<R, E>(
                            evidence,
                            beam.axis,
                            cone,
                            (r, a),
                            &mut heard[i],
                            None,
                        )
                    } else {
                        cell_evidence::<R, E>(evidence, beam.axis, cone, r, a, None)
                    };
                    updated += usize::from(rule.fuse(cell, e));
                }
            }
            updated
        })
    }

    fn fill(&mut self, geometry: &GridGeometry, sensor: SensorCell) {
        let n = geometry.cells_per_side();
        self.grid_angles.clear();
        self.grid_length.clear();
        for y in 0..n {
            for x in 0..n {
                let (r, a) = sensor.polar(x as i64 - sensor.cell[0], y as i64 - sensor.cell[1]);
                self.grid_length.push(r);
                self.grid_angles.push(a);
            }
        }
        self.angle_inside.resize(n * n, 0);
        self.sensor = Some(sensor);
    }
}
