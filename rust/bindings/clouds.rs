//! Point clouds: their arguments (`RobotModel.with_cloud`, `points_near`) and conservative voxel
//! downsampling.

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::arrays::{pose_array, rows_of};
use super::errors::{input_error, to_py, type_error};
use crate::geometry::cloud::voxel_downsample as downsample;

/// `points` as a `(N, 3)` float64 buffer (any layout), or an error naming `what`.
pub(super) fn point_rows(points: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let a = pose_array(points, 3, what)?;
    Ok(rows_of(&a).chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect())
}

/// `radius` as a `(N,)` float64 vector, or an error naming it.
pub(super) fn radius_vec(radius: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<f64>> {
    let r: PyReadonlyArray1<f64> =
        radius.extract().map_err(|_| type_error(format!("radius must be a 1-D float64 numpy array of shape ({n},)")))?;
    if r.len() != n {
        return Err(input_error(format!("radius must have shape ({n},); got ({},)", r.len())));
    }
    Ok(r.as_array().to_vec())
}

/// `voxel_downsample()`: centres `(M, 3)`, radii `(M,)`.
type Balls<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>);

/// Conservative voxel downsampling (`cloud::voxel_downsample`): `(points (M, 3), radius (M,))`.
#[pyfunction]
pub(super) fn voxel_downsample<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    radius: &Bound<'py, PyAny>,
    voxel: f64,
) -> PyResult<Balls<'py>> {
    let p = point_rows(points, "points")?;
    let r = radius_vec(radius, p.len())?;
    let (m, mr) = py.detach(|| downsample(&p, &r, voxel)).map_err(to_py)?;
    let n = m.len();
    Ok((PyArray1::from_vec(py, m.into_flattened()).reshape([n, 3])?, PyArray1::from_vec(py, mr)))
}
