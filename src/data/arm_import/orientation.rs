//! Orientation in an export's own convention, and a fixed tool transform from a file.
//!
//! Euler angles come in twelve orders and two readings: *intrinsic* (each turn about the
//! axis as already turned: R = R₁(a)·R₂(b)·R₃(c)) or *extrinsic* (each about the fixed
//! frame's axis: R = R₃(c)·R₂(b)·R₁(a)), where the first column turns about the first
//! axis of the order. The pose file's own roll, pitch, yaw is extrinsic `xyz`. A
//! quaternion's columns are named in the order x, y, z, w.

use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::data::recording::{file_err, DataError};

/// Whether each Euler turn is about the turned axis or the fixed one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EulerFrame {
    /// About the axes as already turned: R = R₁·R₂·R₃.
    Intrinsic,
    /// About the fixed frame's axes: R = R₃·R₂·R₁.
    Extrinsic,
}

/// An Euler order such as `xyz` or `zyz`: the axis of each column's turn (0 = x).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EulerOrder(pub [usize; 3]);

impl EulerOrder {
    /// Parses `xyz`, `ZYX`, `zyz`, …: three axes, no axis twice in a row.
    ///
    /// ```
    /// use iastgcn::data::arm_import::orientation::EulerOrder;
    ///
    /// assert_eq!(EulerOrder::parse("zyx").unwrap().0, [2, 1, 0]);
    /// assert!(EulerOrder::parse("xxy").is_err());
    /// ```
    pub fn parse(text: &str) -> Result<EulerOrder, String> {
        let axes: Vec<usize> = text
            .chars()
            .map(|c| match c.to_ascii_lowercase() {
                'x' => Ok(0),
                'y' => Ok(1),
                'z' => Ok(2),
                other => Err(format!("{other:?} is not an axis (x, y or z)")),
            })
            .collect::<Result<_, _>>()
            .map_err(|e| format!("Euler order {text:?}: {e}"))?;
        let [a, b, c] = <[usize; 3]>::try_from(axes)
            .map_err(|_| format!("Euler order {text:?}: three axes, such as xyz or zyz"))?;
        if a == b || b == c {
            return Err(format!(
                "Euler order {text:?}: the same axis twice in a row turns about one axis"
            ));
        }
        Ok(EulerOrder([a, b, c]))
    }
}

/// The rotation of Euler `angles` (rad, in column order) of `order` read as `frame`.
///
/// ```
/// use iastgcn::data::arm_import::orientation::{euler_rotation, EulerFrame, EulerOrder};
/// use nalgebra::UnitQuaternion;
///
/// // Extrinsic xyz is nalgebra's roll, pitch, yaw; intrinsic zyx is the same rotation.
/// let (r, p, y) = (0.1, -0.2, 0.3);
/// let rpy = UnitQuaternion::from_euler_angles(r, p, y);
/// let xyz = EulerOrder::parse("xyz").unwrap();
/// let zyx = EulerOrder::parse("zyx").unwrap();
/// assert!(euler_rotation([r, p, y], xyz, EulerFrame::Extrinsic).angle_to(&rpy) < 1e-12);
/// assert!(euler_rotation([y, p, r], zyx, EulerFrame::Intrinsic).angle_to(&rpy) < 1e-12);
/// ```
pub fn euler_rotation(
    angles: [f64; 3],
    order: EulerOrder,
    frame: EulerFrame,
) -> UnitQuaternion<f64> {
    let turn = |k: usize| {
        let mut axis = Vector3::zeros();
        axis[order.0[k]] = 1.0;
        UnitQuaternion::from_scaled_axis(axis * angles[k])
    };
    match frame {
        EulerFrame::Intrinsic => turn(0) * turn(1) * turn(2),
        EulerFrame::Extrinsic => turn(2) * turn(1) * turn(0),
    }
}

/// How far a quaternion's norm may be from 1 (rounding in an export) before it is
/// refused as not a rotation (columns in another order, or not a quaternion).
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// The rotation of the quaternion `[x, y, z, w]`, or why it is not one.
///
/// ```
/// use iastgcn::data::arm_import::orientation::quaternion_rotation;
///
/// let half = std::f64::consts::FRAC_1_SQRT_2;
/// let q = quaternion_rotation([0.0, 0.0, half, half]).unwrap();
/// assert!((q.angle().to_degrees() - 90.0).abs() < 1e-9);
/// assert!(quaternion_rotation([0.0, 0.0, 0.5, 0.5]).is_err());
/// ```
pub fn quaternion_rotation(xyzw: [f64; 4]) -> Result<UnitQuaternion<f64>, String> {
    let [x, y, z, w] = xyzw;
    let q = nalgebra::Quaternion::new(w, x, y, z);
    let norm = q.norm();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "the quaternion (x, y, z, w) = ({x}, {y}, {z}, {w}) has norm {norm:.6}, not 1: \
             are the columns named in the order x, y, z, w?"
        ));
    }
    Ok(UnitQuaternion::from_quaternion(q))
}

/// How far a tool file's rotation may be from orthonormal (the entries' rounding).
pub const ROTATION_TOLERANCE: f64 = 1e-4;

/// Reads a fixed transform from a text file: a 4×4 homogeneous matrix, one row a line,
/// numbers separated by spaces, tabs or commas, the translation in mm, the last row
/// `0 0 0 1`. A rotation that is not orthonormal with determinant +1 (to
/// [`ROTATION_TOLERANCE`]) is refused, naming the file.
pub fn read_transform(path: &Path) -> Result<Isometry3<f64>, DataError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|e| file_err(&file, e.to_string()))?;
    parse_transform(&text, &file)
}

/// [`read_transform`] on the file's text (`file` names it in errors).
///
/// ```
/// use iastgcn::data::arm_import::orientation::parse_transform;
///
/// let t = parse_transform("0 1 0 0\n-1 0 0 0\n0 0 1 -109\n0 0 0 1\n", "t.txt")?;
/// assert_eq!(t.translation.vector.z, -109.0);
/// assert!((t.rotation.angle().to_degrees() - 90.0).abs() < 1e-9);
/// assert!(parse_transform("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "t.txt").is_err());
/// # Ok::<(), iastgcn::data::DataError>(())
/// ```
pub fn parse_transform(text: &str, file: &str) -> Result<Isometry3<f64>, DataError> {
    let at = |line: usize, message: String| DataError::Line {
        file: file.to_string(),
        line: line as u64,
        message,
    };
    let mut rows: Vec<[f64; 4]> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let cells: Vec<&str> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|c| !c.is_empty())
            .collect();
        if cells.is_empty() {
            continue;
        }
        let values = cells
            .iter()
            .map(|c| {
                c.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| at(i + 1, format!("{c:?} is not a finite number")))
            })
            .collect::<Result<Vec<f64>, _>>()?;
        let row = <[f64; 4]>::try_from(values.as_slice()).map_err(|_| {
            at(
                i + 1,
                format!("{} numbers; a row of the 4×4 matrix has 4", values.len()),
            )
        })?;
        if rows.len() == 4 {
            return Err(at(i + 1, "more than four rows; the matrix is 4×4".into()));
        }
        rows.push(row);
    }
    if rows.len() != 4 {
        return Err(file_err(
            file,
            format!("{} rows; the matrix is 4×4, one row a line", rows.len()),
        ));
    }
    if rows[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(file_err(
            file,
            format!("the last row is {:?}, not 0 0 0 1", rows[3]),
        ));
    }
    let r = Matrix3::from_fn(|i, j| rows[i][j]);
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if off > ROTATION_TOLERANCE || r.determinant() <= 0.0 {
        return Err(file_err(
            file,
            format!(
                "the upper-left 3×3 block is not a rotation (RᵀR differs from I by {off:.2e}, \
                 det R = {:.6})",
                r.determinant()
            ),
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    let t = Translation3::new(rows[0][3], rows[1][3], rows[2][3]);
    Ok(Isometry3::from_parts(t, rotation))
}
