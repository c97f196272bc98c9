//! The workpiece: a concave conic mirror facing the robot (base z points down at it).

use nalgebra::Vector3;

use crate::robot::ToolTarget;

/// A concave conic surface of revolution (sphere for `conic = 0`, paraboloid for −1),
/// vertex at `(0, 0, vertex_z)` in the base frame, facing up towards the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mirror {
    /// Clear aperture, mm.
    pub diameter: f64,
    /// Vertex radius of curvature, mm.
    pub radius_of_curvature: f64,
    /// Conic constant k.
    pub conic: f64,
    /// Depth of the vertex below the base, mm.
    pub vertex_z: f64,
}

impl Default for Mirror {
    /// The paper's 510 mm primary mirror as a sphere at f/1.5, placed where the pad sits
    /// at home.
    fn default() -> Mirror {
        Mirror {
            diameter: 510.0,
            radius_of_curvature: 1530.0,
            conic: 0.0,
            vertex_z: 1095.0,
        }
    }
}

impl Mirror {
    /// Half the clear aperture, mm.
    pub fn radius(&self) -> f64 {
        0.5 * self.diameter
    }

    /// Sag (depth below the edge plane's normal direction, towards the robot) at radial
    /// distance `rho`, and its derivative.
    fn sag(&self, rho: f64) -> (f64, f64) {
        let c = 1.0 / self.radius_of_curvature;
        let q = 1.0 - (1.0 + self.conic) * c * c * rho * rho;
        let s = c * rho * rho / (1.0 + q.sqrt());
        let ds = c * rho / q.sqrt();
        (s, ds)
    }

    /// The surface point above `(x, y)` and the tool axis there: the surface normal
    /// pointing into the glass, so the tool presses along it.
    pub fn target(&self, x: f64, y: f64) -> ToolTarget {
        let rho = x.hypot(y);
        let (s, ds) = self.sag(rho);
        let (gx, gy) = if rho > 0.0 {
            (ds * x / rho, ds * y / rho)
        } else {
            (0.0, 0.0)
        };
        ToolTarget {
            // The surface rises towards the robot (−z) away from the vertex.
            position: Vector3::new(x, y, self.vertex_z - s),
            axis: Vector3::new(gx, gy, 1.0).normalize(),
        }
    }
}
