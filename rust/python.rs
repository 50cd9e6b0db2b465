//! The only file that knows Python: pyo3 bindings over the core. Heavy calls release the GIL.
//! Documented for users in `python/profrobot/_core.pyi`.

use std::borrow::Cow;

use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::conversion::FromPyObjectOwned;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBytes, PyDict, PyTuple, PyType};

use crate::cloud::voxel_downsample as downsample;
use crate::collide::{label_batch, LabelOptions};
use crate::couplings::Coupling;
use crate::desc::{CloudDesc, ModelDesc};
use crate::error::Error;
use crate::fastpath::{certified_batch, collides_batch};
use crate::filter::points_near_model;
use crate::ik::{ik, IkOptions, IkOutcome, IkTarget};
use crate::images;
use crate::interpolate::interpolate_so2;
use crate::kinematics::forward_kinematics;
use crate::model::RobotModel;
use crate::motion::prove_apart;
use crate::motion::{certify_motions, Motion};
use crate::oracle::{nearest_free, OracleOptions};
use crate::pairs::PairKind;
use crate::plan::{plan_path, PlanOptions, PlanStatus};
use crate::real::Real;
use crate::render;
use crate::sample::sample_uniform;
use crate::splat::Cutoff;
use crate::threads::with_threads;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

create_exception!(
    profrobot._core,
    ProfrobotError,
    PyException,
    "Root of every error profrobot raises on purpose (profrobot.errors lists the family)."
);

// The error classes with two bases (ours and Python's own: bad input stays a ValueError, a wrong
// dtype a TypeError). `create_exception!` takes one base, so they are made once, at import, with
// `type(name, bases, namespace)`, and kept here for the raising code.
static INPUT_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static INPUT_TYPE_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static MODEL_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// Makes the class `name(*bases)`, adds it to the module `m` and keeps it in `cell`.
fn add_error_class<'py>(
    m: &Bound<'py, PyModule>,
    cell: &PyOnceLock<Py<PyType>>,
    name: &str,
    bases: Vec<Bound<'py, PyType>>,
    doc: &str,
) -> PyResult<Bound<'py, PyType>> {
    let py = m.py();
    let ns = PyDict::new(py);
    ns.set_item("__module__", "profrobot._core")?;
    ns.set_item("__doc__", doc)?;
    let bases = PyTuple::new(py, bases)?;
    let class = py.get_type::<PyType>().call1((name, bases, ns))?.cast_into::<PyType>()?;
    m.add(name, &class)?;
    let _ = cell.set(py, class.clone().unbind());
    Ok(class)
}

fn raise(cell: &PyOnceLock<Py<PyType>>, msg: String) -> PyErr {
    Python::attach(|py| match cell.get(py) {
        Some(t) => PyErr::from_type(t.bind(py).clone(), msg),
        None => ProfrobotError::new_err(msg), // not reached: the module's init fills the cells
    })
}

/// Bad input (a shape, a NaN, an option): `profrobot.errors.InputError`, a ValueError.
fn input_error(msg: impl Into<String>) -> PyErr {
    raise(&INPUT_ERROR, msg.into())
}

/// A wrong type or dtype: `profrobot.errors.InputTypeError`, a TypeError.
fn type_error(msg: impl Into<String>) -> PyErr {
    raise(&INPUT_TYPE_ERROR, msg.into())
}

/// A model the core cannot label exactly: `profrobot.errors.ModelError`, an InputError.
fn model_error(msg: impl Into<String>) -> PyErr {
    raise(&MODEL_ERROR, msg.into())
}

fn to_py(e: Error) -> PyErr {
    match e {
        // A pair the narrow phase cannot decide (`collide.rs`): the model cannot be labelled
        // exactly; never a label.
        Error::InvalidModel(_) | Error::Undecided(_) => model_error(e.to_string()),
        Error::InvalidInput(_) => input_error(e.to_string()),
    }
}

fn item<'py>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?.ok_or_else(|| input_error(format!("model arrays lack '{key}'")))
}

/// Extracts `d[key]` as `T`; on failure a TypeError saying what was `expected`.
fn typed<'py, T: FromPyObjectOwned<'py>>(d: &Bound<'py, PyDict>, key: &str, expected: &str) -> PyResult<T> {
    item(d, key)?.extract::<T>().map_err(|_| type_error(format!("model array '{key}' must be {expected}")))
}

fn rows<const N: usize>(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<[f64; N]>> {
    let a: PyReadonlyArray2<f64> = typed(d, key, &format!("a float64 array of shape (n, {N})"))?;
    let shape = a.shape();
    if shape[1] != N {
        return Err(input_error(format!("model array '{key}' must have {N} columns; got shape {shape:?}")));
    }
    let a = a.as_array();
    Ok(a.rows().into_iter().map(|r| std::array::from_fn(|i| r[i])).collect())
}

fn int_rows(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<[i32; 2]>> {
    let a: PyReadonlyArray2<i32> = typed(d, key, "an int32 array of shape (n, 2)")?;
    if a.shape()[1] != 2 {
        return Err(input_error(format!("model array '{key}' must have 2 columns")));
    }
    Ok(a.as_array().rows().into_iter().map(|r| [r[0], r[1]]).collect())
}

fn vec1<T: numpy::Element + Copy + 'static>(d: &Bound<'_, PyDict>, key: &str) -> PyResult<Vec<T>> {
    let a: PyReadonlyArray1<T> = typed(d, key, &format!("a 1-D {} array", std::any::type_name::<T>()))?;
    Ok(a.as_array().to_vec())
}

fn desc_from_dict(d: &Bound<'_, PyDict>) -> PyResult<ModelDesc> {
    Ok(ModelDesc {
        body_parent: vec1(d, "body_parent")?,
        body_weld: vec1(d, "body_weld")?,
        body_pos: rows(d, "body_pos")?,
        body_quat: rows(d, "body_quat")?,
        jnt_type: vec1(d, "jnt_type")?,
        jnt_body: vec1(d, "jnt_body")?,
        jnt_pos: rows(d, "jnt_pos")?,
        jnt_axis: rows(d, "jnt_axis")?,
        jnt_qpos0: vec1(d, "jnt_qpos0")?,
        jnt_range: rows(d, "jnt_range")?,
        jnt_limited: vec1(d, "jnt_limited")?,
        geom_id: vec1(d, "geom_id")?,
        geom_type: vec1(d, "geom_type")?,
        geom_body: vec1(d, "geom_body")?,
        geom_pos: rows(d, "geom_pos")?,
        geom_quat: rows(d, "geom_quat")?,
        geom_size: rows(d, "geom_size")?,
        geom_contype: vec1(d, "geom_contype")?,
        geom_conaffinity: vec1(d, "geom_conaffinity")?,
        geom_margin: vec1(d, "geom_margin")?,
        geom_mesh: vec1(d, "geom_mesh")?,
        mesh_vert_adr: vec1(d, "mesh_vert_adr")?,
        mesh_vert_num: vec1(d, "mesh_vert_num")?,
        mesh_vert: rows(d, "mesh_vert")?,
        exclude: int_rows(d, "exclude")?,
        pair_geom: int_rows(d, "pair_geom")?,
        pair_margin: vec1(d, "pair_margin")?,
        filter_parent: typed(d, "filter_parent", "a bool")?,
        contact_enabled: typed(d, "contact_enabled", "a bool")?,
        jnt_scene: if d.contains("jnt_scene")? { vec1(d, "jnt_scene")? } else { vec![] },
        couplings: if d.contains("eq_dep")? { couplings_from_dict(d)? } else { vec![] },
        cloud: if d.contains("cloud_points")? {
            Some(CloudDesc {
                points: rows(d, "cloud_points")?,
                radius: vec1(d, "cloud_radius")?,
                margin: typed(d, "cloud_margin", "a float")?,
                contype: typed(d, "cloud_contype", "an int")?,
                conaffinity: typed(d, "cloud_conaffinity", "an int")?,
            })
        } else {
            None
        },
    })
}

/// `points` as a `(N, 3)` float64 buffer (any layout), or an error naming `what`.
fn point_rows(points: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let a = pose_array(points, 3, what)?;
    Ok(rows_of(&a).chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect())
}

/// `radius` as a `(N,)` float64 vector, or an error naming it.
fn radius_vec(radius: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<f64>> {
    let r: PyReadonlyArray1<f64> =
        radius.extract().map_err(|_| type_error(format!("radius must be a 1-D float64 numpy array of shape ({n},)")))?;
    if r.len() != n {
        return Err(input_error(format!("radius must have shape ({n},); got ({},)", r.len())));
    }
    Ok(r.as_array().to_vec())
}

/// The joint equalities: `eq_dep` (E,) uint32, `eq_indep` (E,) int32 (-1: none), `eq_coef`
/// (E, 5) and `eq_origin` (E, 2: the dependent's and the independent's qpos0) float64.
fn couplings_from_dict(d: &Bound<'_, PyDict>) -> PyResult<Vec<Coupling>> {
    let dep: Vec<u32> = vec1(d, "eq_dep")?;
    let indep: Vec<i32> = vec1(d, "eq_indep")?;
    let coef: Vec<[f64; 5]> = rows(d, "eq_coef")?;
    let origin: Vec<[f64; 2]> = rows(d, "eq_origin")?;
    if indep.len() != dep.len() || coef.len() != dep.len() || origin.len() != dep.len() {
        return Err(model_error("eq_dep, eq_indep, eq_coef and eq_origin differ in length"));
    }
    Ok((0..dep.len()).map(|e| Coupling { dep: dep[e], indep: indep[e], coef: coef[e], y0: origin[e][0], x0: origin[e][1] }).collect())
}

/// `obj` as a 2-D float64 array with `k` columns (any memory layout), or a TypeError/ValueError
/// naming `what`, the dtype and the shape it wants.
fn pose_array<'py>(obj: &Bound<'py, PyAny>, k: usize, what: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    let a: PyReadonlyArray2<'py, f64> = obj.extract().map_err(|_| {
        let dtype = obj.getattr("dtype").and_then(|d| d.str()).map(|d| d.to_string());
        let ndim = obj.getattr("ndim").and_then(|n| n.extract::<usize>());
        let got = match (dtype, ndim) {
            (Ok(d), Ok(n)) => format!("a {n}-D {d} array"),
            _ => format!("a {}", obj.get_type().name().map(|n| n.to_string()).unwrap_or_default()),
        };
        type_error(format!("{what} must be a 2-D float64 numpy array of shape (B, {k}); got {got}"))
    })?;
    let shape = a.shape();
    if shape[1] != k {
        return Err(input_error(format!("{what} must have shape (B, {k}); got {shape:?}")));
    }
    Ok(a)
}

/// The elements of `a` (any dimension) as one row-major buffer: borrowed when `a` is C-contiguous, otherwise copied
/// element by element through its strides (Fortran order, negative strides, sliced views).
///
/// Exactness: rust-numpy's `as_slice` succeeds for *any* contiguous array, Fortran order
/// included, and would hand back the memory in storage order; reading it as rows silently
/// transposes the poses. Only `is_c_contiguous` guarantees storage order == row order.
///
/// A broadcast constant (every stride 0: one element seen everywhere, e.g. the gradient of a
/// plain sum, or zeros for an unused output) is filled at memset speed in this library's
/// allocator instead of being materialised by the caller (75 MB of fresh pages at 256 views).
fn rows_of<'a, T: numpy::Element + Copy, D: numpy::ndarray::Dimension>(a: &'a numpy::PyReadonlyArray<'_, T, D>) -> Cow<'a, [T]> {
    if a.is_c_contiguous() {
        if let Ok(s) = a.as_slice() {
            return Cow::Borrowed(s);
        }
    }
    let view = a.as_array();
    if let Some(&first) = view.first() {
        if view.strides().iter().all(|&s| s == 0) {
            return Cow::Owned(vec![first; view.len()]);
        }
    }
    Cow::Owned(view.iter().copied().collect())
}

/// `RobotModel.pairs()`: geom ids `(P, 2)`, is-self `(P,)`, margin `(P,)`.
type PairArrays<'py> = (Bound<'py, PyArray2<i32>>, Bound<'py, PyArray1<bool>>, Bound<'py, PyArray1<f64>>);

/// `voxel_downsample()`: centres `(M, 3)`, radii `(M,)`.
type Balls<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>);

/// `RobotModel.forward_kinematics()`: xpos `(B, nbody, 3)`, xquat `(B, nbody, 4)`.
type FrameArrays<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f64>>);

/// The compiled collision model of one robot scene (see `_core.pyi`): the core's
/// `RobotModel`, and the description it was built from, which is what pickles.
#[pyclass(name = "RobotModel", module = "profrobot._core", frozen)]
struct PyRobotModel {
    model: RobotModel,
    desc: ModelDesc,
}

impl PyRobotModel {
    fn from_desc(desc: ModelDesc) -> PyResult<Self> {
        Ok(Self { model: RobotModel::new(desc.clone()).map_err(to_py)?, desc })
    }
}

#[pymethods]
impl PyRobotModel {
    #[new]
    fn new(arrays: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_desc(desc_from_dict(arrays)?)
    }

    /// Pickling: `RobotModel._from_state(bytes)` rebuilds the model from its description
    /// (`ModelDesc::to_bytes`, exact to the bit).
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyBytes>,))> {
        let state = PyBytes::new(slf.py(), &slf.get().desc.to_bytes());
        Ok((slf.get_type().getattr("_from_state")?, (state,)))
    }

    /// The inverse of `__reduce__`: a ProfrobotError (ValueError) for bytes that are not a
    /// model description, ModelError for one the core rejects.
    #[classmethod]
    fn _from_state(_cls: &Bound<'_, PyType>, state: &Bound<'_, PyAny>) -> PyResult<Self> {
        let bytes = state.cast::<PyBytes>().map_err(|_| {
            let got = state.get_type().name().map(|n| n.to_string()).unwrap_or_default();
            type_error(format!("RobotModel state must be bytes; got {got}"))
        })?;
        Self::from_desc(ModelDesc::from_bytes(bytes.as_bytes()).map_err(to_py)?)
    }

    /// This model with the point cloud `points` (N, 3) of radii `radius` (N,) instead of its own
    /// (`None`: no cloud), its balls with geom margin `margin` and MuJoCo's contype /
    /// conaffinity. The MuJoCo geoms' shapes are shared, not built again.
    #[pyo3(signature = (points, radius, margin=0.0, contype=1, conaffinity=1))]
    fn with_cloud(
        &self,
        py: Python<'_>,
        points: Option<&Bound<'_, PyAny>>,
        radius: Option<&Bound<'_, PyAny>>,
        margin: f64,
        contype: u32,
        conaffinity: u32,
    ) -> PyResult<Self> {
        let mut desc = self.desc.clone();
        desc.cloud = match (points, radius) {
            (Some(p), Some(r)) => {
                let points = point_rows(p, "points")?;
                let radius = radius_vec(r, points.len())?;
                Some(CloudDesc { points, radius, margin, contype, conaffinity })
            }
            (None, None) => None,
            _ => return Err(input_error("points and radius are given together, or neither")),
        };
        let model = py.detach(|| self.model.with_cloud(desc.clone())).map_err(to_py)?;
        Ok(Self { model, desc })
    }

    /// `(N,)` uint8 per point of `points` (N, 3, world metres) at `pose` (K,): 1 within `margin`
    /// metres of a robot geom, else 2 within `static_margin` of another geom (the point cloud
    /// excepted; `None`: not tested), else 0 (`filter.rs`).
    #[pyo3(signature = (pose, points, margin, static_margin=None))]
    fn points_near<'py>(
        &self,
        py: Python<'py>,
        pose: &Bound<'py, PyAny>,
        points: &Bound<'py, PyAny>,
        margin: f64,
        static_margin: Option<f64>,
    ) -> PyResult<Bound<'py, PyArray1<u8>>> {
        let model = &self.model;
        let q = pose_array(pose, model.njoint(), "pose")?;
        let q = rows_of(&q).into_owned();
        let points = point_rows(points, "points")?;
        let kind = py.detach(|| points_near_model(model, &q, &points, margin, static_margin)).map_err(to_py)?;
        Ok(PyArray1::from_vec(py, kind))
    }

    #[getter]
    fn njoint(&self) -> usize {
        self.model.njoint()
    }

    #[getter]
    fn nbody(&self) -> usize {
        self.model.nbody()
    }

    #[getter]
    fn ngeom(&self) -> usize {
        self.model.geoms().len()
    }

    #[getter]
    fn npair(&self) -> usize {
        self.model.pairs().len()
    }

    /// `(geom ids (P, 2) int32, is_self (P,) bool, margin (P,) float64)`.
    fn pairs<'py>(&self, py: Python<'py>) -> PyResult<PairArrays<'py>> {
        let geoms = self.model.geoms();
        let pairs = self.model.pairs();
        let ids: Vec<i32> = pairs.iter().flat_map(|p| [geoms[p.g1].mujoco_id, geoms[p.g2].mujoco_id]).collect();
        let is_self: Vec<bool> = pairs.iter().map(|p| p.kind == PairKind::SelfCollision).collect();
        let margin: Vec<f64> = pairs.iter().map(|p| p.margin).collect();
        Ok((PyArray1::from_vec(py, ids).reshape([pairs.len(), 2])?, PyArray1::from_vec(py, is_self), PyArray1::from_vec(py, margin)))
    }

    fn sampling_ranges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let r = self.model.sampling_ranges().map_err(to_py)?;
        let k = r.len();
        PyArray1::from_vec(py, r.into_flattened()).reshape([k, 2])
    }

    fn continuous<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<bool>> {
        PyArray1::from_vec(py, self.model.continuous())
    }

    #[pyo3(signature = (poses, threads=None))]
    fn forward_kinematics<'py>(&self, py: Python<'py>, poses: &Bound<'py, PyAny>, threads: Option<usize>) -> PyResult<FrameArrays<'py>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let (xpos, xquat) = py.detach(|| with_threads(threads, || forward_kinematics(model, q))).map_err(to_py)?.map_err(to_py)?;
        let nb = model.nbody();
        let b = xpos.len() / (3 * nb);
        Ok((PyArray1::from_vec(py, xpos).reshape([b, nb, 3])?, PyArray1::from_vec(py, xquat).reshape([b, nb, 4])?))
    }

    #[pyo3(signature = (poses, *, pairs=false, distance=false, threads=None))]
    fn label<'py>(
        &self,
        py: Python<'py>,
        poses: &Bound<'py, PyAny>,
        pairs: bool,
        distance: bool,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let opts = LabelOptions { pairs, distance };
        let batch = py
            .detach(|| {
                with_threads(threads, || {
                    // (checked first, so that bad input costs no proofs)
                    model.check_poses(q)?;
                    prove_apart(model);
                    label_batch(model, q, opts)
                })
            })
            .map_err(to_py)?
            .map_err(to_py)?;
        let labels = &batch.labels;
        let out = PyDict::new(py);
        out.set_item("collides", PyArray1::from_iter(py, labels.iter().map(|l| l.collides())))?;
        out.set_item("self_collides", PyArray1::from_iter(py, labels.iter().map(|l| l.self_collides)))?;
        out.set_item("scene_collides", PyArray1::from_iter(py, labels.iter().map(|l| l.scene_collides)))?;
        out.set_item("n_pairs", PyArray1::from_iter(py, labels.iter().map(|l| l.n_pairs as i32)))?;
        if distance {
            out.set_item("min_distance", PyArray1::from_iter(py, labels.iter().map(|l| l.min_distance)))?;
        }
        if pairs {
            let m = batch.colliding_pairs.len();
            let flat: Vec<i64> = batch.colliding_pairs.iter().flat_map(|&[p, k]| [p as i64, k as i64]).collect();
            out.set_item("colliding_pairs", PyArray1::from_vec(py, flat).reshape([m, 2])?)?;
        }
        Ok(out)
    }

    /// `(B,)` bool: whether each pose collides (`label(..)["collides"]`, by the fast path).
    #[pyo3(signature = (poses, *, threads=None))]
    fn collides<'py>(&self, py: Python<'py>, poses: &Bound<'py, PyAny>, threads: Option<usize>) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let out = py
            .detach(|| {
                with_threads(threads, || {
                    model.check_poses(q)?;
                    prove_apart(model);
                    collides_batch(model, q)
                })
            })
            .map_err(to_py)?
            .map_err(to_py)?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// Whether each pose is certified free at `clearance` metres (see `_core.pyi` and
    /// `fastpath.rs`).
    #[pyo3(signature = (poses, clearance, threads=None))]
    fn certified<'py>(
        &self,
        py: Python<'py>,
        poses: &Bound<'py, PyAny>,
        clearance: f64,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyArray1<bool>>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let out = py
            .detach(|| {
                with_threads(threads, || {
                    model.check_poses(q)?;
                    crate::broad::check_clearance(clearance)?;
                    prove_apart(model);
                    certified_batch(model, q, clearance)
                })
            })
            .map_err(to_py)?
            .map_err(to_py)?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// The continuous certificate of each straight motion `starts[i] -> goals[i]` (see
    /// `_core.pyi` and `motion.rs`).
    #[pyo3(signature = (starts, goals, clearance, threads=None))]
    fn certify_motions<'py>(
        &self,
        py: Python<'py>,
        starts: &Bound<'py, PyAny>,
        goals: &Bound<'py, PyAny>,
        clearance: f64,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let (a, b) = (pose_array(starts, k, "starts")?, pose_array(goals, k, "goals")?);
        let (a, b) = (rows_of(&a), rows_of(&b));
        let (a, b): (&[f64], &[f64]) = (&a, &b);
        let r = py.detach(|| with_threads(threads, || certify_motions(model, a, b, clearance))).map_err(to_py)?.map_err(to_py)?;
        let verdict: Vec<u8> = r
            .iter()
            .map(|(m, _)| match m {
                Motion::Certified => 0,
                Motion::Blocked(_) => 1,
                Motion::Unproven => 2,
            })
            .collect();
        let at: Vec<f64> = r
            .iter()
            .map(|(m, _)| match m {
                Motion::Blocked(t) => *t,
                _ => f64::NAN,
            })
            .collect();
        let states: Vec<i64> = r.iter().map(|&(_, n)| n as i64).collect();
        let out = PyDict::new(py);
        out.set_item("verdict", PyArray1::from_vec(py, verdict))?;
        out.set_item("blocked_at", PyArray1::from_vec(py, at))?;
        out.set_item("states", PyArray1::from_vec(py, states))?;
        Ok(out)
    }

    /// The nearest free pose found for each pose (see `_core.pyi` and `oracle.rs`).
    #[pyo3(signature = (poses, *, directions=256, step=0.02, tolerance=1e-4, refine=1024, max_distance=None, seed=0, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn nearest_free<'py>(
        &self,
        py: Python<'py>,
        poses: &Bound<'py, PyAny>,
        directions: usize,
        step: f64,
        tolerance: f64,
        refine: usize,
        max_distance: Option<f64>,
        seed: u64,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let poses = pose_array(poses, k, "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let max_distance = max_distance.unwrap_or(f64::INFINITY);
        let opts = OracleOptions { directions, step, tolerance, refine, max_distance, seed };
        let r = py.detach(|| with_threads(threads, || nearest_free(model, q, &opts))).map_err(to_py)?.map_err(to_py)?;
        let b = r.distance.len();
        let out = PyDict::new(py);
        out.set_item("distance", PyArray1::from_vec(py, r.distance))?;
        out.set_item("poses", PyArray1::from_vec(py, r.poses).reshape([b, k])?)?;
        out.set_item("checks", PyArray1::from_iter(py, r.checks.iter().map(|&c| c as i64)))?;
        Ok(out)
    }

    /// A free path from `start` to `goal` (see `_core.pyi` and `plan.rs`).
    #[pyo3(signature = (start, goal, *, resolution=0.01, max_time=10.0, seed=0, range=0.0, max_iterations=200_000, shortcut_rounds=200, verify=10, continuous=true, clearance=1e-6, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn plan_path<'py>(
        &self,
        py: Python<'py>,
        start: &Bound<'py, PyAny>,
        goal: &Bound<'py, PyAny>,
        resolution: f64,
        max_time: f64,
        seed: u64,
        range: f64,
        max_iterations: usize,
        shortcut_rounds: usize,
        verify: usize,
        continuous: bool,
        clearance: f64,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let pose = |obj: &Bound<'py, PyAny>, what: &str| -> PyResult<Vec<f64>> {
            let a: PyReadonlyArray1<'py, f64> =
                obj.extract().map_err(|_| type_error(format!("{what} must be a 1-D float64 numpy array of shape (K,)")))?;
            Ok(a.as_array().to_vec())
        };
        let (s, g) = (pose(start, "start")?, pose(goal, "goal")?);
        let opts = PlanOptions { resolution, max_time, seed, range, max_iterations, shortcut_rounds, verify, continuous, clearance };
        let model = &self.model;
        let r = py.detach(|| with_threads(threads, || plan_path(model, &s, &g, &opts))).map_err(to_py)?.map_err(to_py)?;
        let k = model.njoint();
        let m = r.path.len() / k.max(1);
        let out = PyDict::new(py);
        out.set_item("path", PyArray1::from_vec(py, r.path).reshape([m, k])?)?;
        let status = match r.status {
            PlanStatus::Direct => "direct",
            PlanStatus::Connected => "connected",
            PlanStatus::TimeOut => "time_out",
            PlanStatus::IterationLimit => "iteration_limit",
        };
        out.set_item("status", status)?;
        out.set_item("checks", r.checks)?;
        out.set_item("iterations", r.iterations)?;
        out.set_item("tree_sizes", (r.tree_sizes[0], r.tree_sizes[1]))?;
        out.set_item("raw_waypoints", r.raw_waypoints)?;
        out.set_item("seconds", r.seconds)?;
        Ok(out)
    }

    /// Inverse kinematics of a frame (see `_core.pyi` and `ik.rs`): `targets_pos` `(N, 3)`,
    /// `targets_quat` `(N, 4)` `(w, x, y, z)` or None (position only), `starts` `(N, K)`; the frame
    /// is body `body` offset by `local_pos`, `local_quat`.
    #[pyo3(signature = (targets_pos, targets_quat, starts, body, local_pos, local_quat, *, seeds=128, iterations=60, tol_pos=1e-6, tol_rot=1e-6, clearance=1e-6, seed=0, escape=true, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn ik<'py>(
        &self,
        py: Python<'py>,
        targets_pos: &Bound<'py, PyAny>,
        targets_quat: Option<&Bound<'py, PyAny>>,
        starts: &Bound<'py, PyAny>,
        body: usize,
        local_pos: [f64; 3],
        local_quat: [f64; 4],
        seeds: usize,
        iterations: usize,
        tol_pos: f64,
        tol_rot: f64,
        clearance: f64,
        seed: u64,
        escape: bool,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let pos = pose_array(targets_pos, 3, "targets_pos")?;
        let n = pos.shape()[0];
        let pos = rows_of(&pos);
        let quat = match targets_quat {
            None => None,
            Some(q) => {
                let q = pose_array(q, 4, "targets_quat")?;
                if q.shape()[0] != n {
                    return Err(input_error(format!("targets_quat has {} rows, targets_pos {n}", q.shape()[0])));
                }
                Some(rows_of(&q).into_owned())
            }
        };
        let starts = pose_array(starts, k, "starts")?;
        if starts.shape()[0] != n {
            return Err(input_error(format!("starts has {} rows for {n} targets", starts.shape()[0])));
        }
        let starts = rows_of(&starts);
        let starts: &[f64] = &starts;
        let unit = |q: &[f64]| UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]));
        let targets: Vec<IkTarget> = (0..n)
            .map(|i| IkTarget { pos: [pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]], rot: quat.as_ref().map(|q| unit(&q[4 * i..4 * i + 4])) })
            .collect();
        let local = Isometry3::from_parts(Translation3::from(local_pos), unit(&local_quat));
        let opts = IkOptions { body, local, seeds, iterations, tol_pos, tol_rot, clearance, seed, escape };
        let scene = &self.desc.jnt_scene;
        let r = py.detach(|| with_threads(threads, || ik(model, &targets, starts, scene, &opts))).map_err(to_py)?.map_err(to_py)?;
        let out = PyDict::new(py);
        out.set_item("poses", PyArray1::from_iter(py, r.iter().flat_map(|a| a.pose.iter().copied())).reshape([n, k])?)?;
        out.set_item(
            "outcome",
            PyArray1::from_iter(
                py,
                r.iter().map(|a| match a.outcome {
                    IkOutcome::Certified => 0u8,
                    IkOutcome::Unreachable => 1,
                    IkOutcome::Colliding => 2,
                }),
            ),
        )?;
        out.set_item("reached", PyArray1::from_iter(py, r.iter().map(|a| a.reached)))?;
        out.set_item("position_error", PyArray1::from_iter(py, r.iter().map(|a| a.pos_err)))?;
        out.set_item("rotation_error", PyArray1::from_iter(py, r.iter().map(|a| a.rot_err)))?;
        out.set_item("iterations", PyArray1::from_iter(py, r.iter().map(|a| a.iterations as i64)))?;
        out.set_item("seeds", PyArray1::from_iter(py, r.iter().map(|a| a.seeds as i64)))?;
        Ok(out)
    }

    #[pyo3(signature = (n, seed, threads=None))]
    fn sample<'py>(&self, py: Python<'py>, n: usize, seed: u64, threads: Option<usize>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let ranges = self.model.sampling_ranges().map_err(to_py)?;
        let k = ranges.len();
        let v = py.detach(|| with_threads(threads, || sample_uniform(&ranges, n, seed))).map_err(to_py)?.map_err(to_py)?;
        PyArray1::from_vec(py, v).reshape([n, k])
    }
}

/// `(B, steps, K)` interpolation of `(B, K)` start/goal poses (see `_core.pyi`).
#[pyfunction]
fn interpolate<'py>(
    py: Python<'py>,
    start: &Bound<'py, PyAny>,
    goal: &Bound<'py, PyAny>,
    steps: usize,
    continuous: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyArray3<f64>>> {
    let continuous: PyReadonlyArray1<'py, bool> =
        continuous.extract().map_err(|_| type_error("continuous must be a 1-D bool numpy array of shape (K,)"))?;
    let cont = continuous.as_array().to_vec();
    let k = cont.len();
    let (start, goal) = (pose_array(start, k, "start")?, pose_array(goal, k, "goal")?);
    let (s, g) = (rows_of(&start), rows_of(&goal));
    let b = start.shape()[0];
    let v = py.detach(|| interpolate_so2(&s, &g, steps, &cont)).map_err(to_py)?;
    PyArray1::from_vec(py, v).reshape([b, steps, k])
}

/// `(first non-finite, first outside its column's [lo, hi])` flat indices of `(B, K)` poses, or
/// `None` each (`validate::first_bad_entries`; see `_core.pyi`).
#[pyfunction]
fn first_bad_entries<'py>(
    py: Python<'py>,
    poses: &Bound<'py, PyAny>,
    lo: PyReadonlyArray1<'py, f64>,
    hi: PyReadonlyArray1<'py, f64>,
) -> PyResult<(Option<usize>, Option<usize>)> {
    let (lo, hi) = (lo.as_array().to_vec(), hi.as_array().to_vec());
    if lo.is_empty() || lo.len() != hi.len() {
        return Err(input_error(format!("lo and hi must both have shape (K,) with K >= 1; got {} and {}", lo.len(), hi.len())));
    }
    let poses = pose_array(poses, lo.len(), "poses")?;
    let q = rows_of(&poses);
    Ok(py.detach(|| crate::validate::first_bad_entries(&q, &lo, &hi)))
}

/// Conservative voxel downsampling (`cloud::voxel_downsample`): `(points (M, 3), radius (M,))`.
#[pyfunction]
fn voxel_downsample<'py>(py: Python<'py>, points: &Bound<'py, PyAny>, radius: &Bound<'py, PyAny>, voxel: f64) -> PyResult<Balls<'py>> {
    let p = point_rows(points, "points")?;
    let r = radius_vec(radius, p.len())?;
    let (m, mr) = py.detach(|| downsample(&p, &r, voxel)).map_err(to_py)?;
    let n = m.len();
    Ok((PyArray1::from_vec(py, m.into_flattened()).reshape([n, 3])?, PyArray1::from_vec(py, mr)))
}

/// The backward state of one `render_forward` call (the scene, the tile lists and every
/// composited pair), in the dtype it was computed in; opaque to Python.
enum AnyRenderState {
    F32(render::State<f32>),
    F64(render::State<f64>),
}

#[pyclass(name = "RenderState", module = "profrobot._core", frozen)]
struct PyRenderState {
    state: AnyRenderState,
}

/// `obj` as a `T` array of shape `want` (`None`: any size, which is returned), copied in
/// logical order; errors name the argument.
fn real_array<T: numpy::Element + Copy>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    want: &[Option<usize>],
    dtype: &str,
) -> PyResult<(Vec<T>, Vec<usize>)> {
    let (a, shape) = real_view::<T>(obj, name, want, dtype)?;
    Ok((rows_of(&a).into_owned(), shape))
}

/// [`real_array`] without the copy: the checked array itself (read it with [`rows_of`], which
/// borrows a C-contiguous one).
fn real_view<'py, T: numpy::Element + Copy>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    want: &[Option<usize>],
    dtype: &str,
) -> PyResult<(numpy::PyReadonlyArrayDyn<'py, T>, Vec<usize>)> {
    let show = || {
        let parts: Vec<String> = want.iter().map(|d| d.map_or("*".to_string(), |k| k.to_string())).collect();
        format!("({})", parts.join(", "))
    };
    let a: numpy::PyReadonlyArrayDyn<'py, T> = obj.extract().map_err(|_| {
        type_error(format!("render_forward: {name} must be a {dtype} numpy array of shape {} (every float input the same dtype)", show()))
    })?;
    let shape = a.shape().to_vec();
    if shape.len() != want.len() || shape.iter().zip(want).any(|(s, w)| w.is_some_and(|w| w != *s)) {
        return Err(input_error(format!("render_forward: {name} must have shape {}; got {shape:?}", show())));
    }
    Ok((a, shape))
}

/// The inputs of `render_forward`, read for one dtype.
struct SceneArgs<'a, 'py> {
    opacities: &'a Bound<'py, PyAny>,
    viewmats: &'a Bound<'py, PyAny>,
    ks: &'a Bound<'py, PyAny>,
    views: Vec<[usize; 2]>,
    width: usize,
    height: usize,
    world: Option<(&'a Bound<'py, PyAny>, &'a Bound<'py, PyAny>)>,
    frames: Option<&'a Bound<'py, PyAny>>,
    /// body_rot, body_pos, body, local_means, scales; the local rotations.
    rigid: Option<([&'a Bound<'py, PyAny>; 5], Rots<'a, 'py>)>,
    colors: Option<&'a Bound<'py, PyAny>>,
    sh: Option<&'a Bound<'py, PyAny>>,
    cutoff: Cutoff,
}

/// `local_rots=` (N, 3, 3) or `local_quats=` (N, 4).
#[derive(Clone, Copy)]
enum Rots<'a, 'py> {
    Matrices(&'a Bound<'py, PyAny>),
    Quats(&'a Bound<'py, PyAny>),
}

fn read_scene<T: numpy::Element + Real>(a: &SceneArgs<'_, '_>, dtype: &str) -> PyResult<render::Scene<T>> {
    let v = a.views.len();
    let (means, covs, frames, rigid, p, n) = match (a.world, a.rigid) {
        (Some((means, covs)), None) => {
            let (means, ms) = real_array::<T>(means, "means", &[None, None, Some(3)], dtype)?;
            let (p, n) = (ms[0], ms[1]);
            let (covs, _) = real_array::<T>(covs, "covs", &[Some(p), Some(n), Some(3), Some(3)], dtype)?;
            let frames = a.frames.map(|f| real_array::<T>(f, "frames", &[Some(p), Some(n), Some(3), Some(3)], dtype)).transpose()?;
            (means, covs, frames.map(|f| f.0), None, p, n)
        }
        (None, Some(([body_rot, body_pos, body, local_means, scales], local_rots))) => {
            let (body_rot, bs) = real_array::<T>(body_rot, "body_rot", &[None, None, Some(3), Some(3)], dtype)?;
            let (p, nb) = (bs[0], bs[1]);
            let (body_pos, _) = real_array::<T>(body_pos, "body_pos", &[Some(p), Some(nb), Some(3)], dtype)?;
            let body: Vec<i64> = body
                .extract::<numpy::PyReadonlyArray1<'_, i64>>()
                .map_err(|_| type_error("render_forward: body must be an int64 numpy array of shape (N,)"))?
                .as_array()
                .to_vec();
            let n = body.len();
            if let Some(i) = body.iter().position(|&b| b < 0 || b as usize >= nb) {
                return Err(input_error(format!("render_forward: body[{i}] = {} is out of range ({nb} bodies)", body[i])));
            }
            let rigid = render::Rigid {
                nbody: nb,
                body_rot,
                body_pos,
                body: body.iter().map(|&b| b as u32).collect(),
                means: real_array::<T>(local_means, "local_means", &[Some(n), Some(3)], dtype)?.0,
                rots: match local_rots {
                    Rots::Matrices(r) => {
                        render::LocalRots::Matrices(real_array::<T>(r, "local_rots", &[Some(n), Some(3), Some(3)], dtype)?.0)
                    }
                    Rots::Quats(q) => render::LocalRots::Quats(real_array::<T>(q, "local_quats", &[Some(n), Some(4)], dtype)?.0),
                },
                scales: real_array::<T>(scales, "scales", &[Some(n), Some(3)], dtype)?.0,
            };
            (Vec::new(), Vec::new(), None, Some(rigid), p, n)
        }
        _ => return Err(input_error("render_forward: give either means= and covs= or the rigid arrays (body_rot=, ...)")),
    };
    let per_view = |obj: &Bound<'_, PyAny>, name: &str, tail: &[Option<usize>]| -> PyResult<(Vec<T>, bool)> {
        let nd = obj.getattr("ndim")?.extract::<usize>().unwrap_or(0);
        let per = nd == tail.len() + 2;
        let mut want = if per { vec![Some(v), Some(n)] } else { vec![Some(n)] };
        want.extend_from_slice(tail);
        Ok((real_array::<T>(obj, name, &want, dtype)?.0, per))
    };
    let (opacity, opacity_per_view) = per_view(a.opacities, "opacities", &[])?;
    let colors = match (a.colors, a.sh) {
        (Some(c), None) => {
            let (rgb, per_view) = per_view(c, "colors", &[Some(3)])?;
            render::Colors::Rgb { per_view, rgb }
        }
        (None, Some(s)) => {
            let (coeffs, shape) = real_array::<T>(s, "sh", &[Some(n), None, Some(3)], dtype)?;
            render::Colors::Sh { nsh: shape[1], coeffs }
        }
        _ => return Err(input_error("render_forward: give exactly one of colors= and sh=")),
    };
    let (vm, vs) = real_array::<T>(a.viewmats, "viewmats", &[None, Some(4), Some(4)], dtype)?;
    let c = vs[0];
    let (k, _) = real_array::<T>(a.ks, "Ks", &[Some(c), Some(3), Some(3)], dtype)?;
    let cameras = (0..c)
        .map(|i| {
            let m = &vm[16 * i..16 * i + 16];
            let kk = &k[9 * i..9 * i + 9];
            render::Camera {
                r: [[m[0], m[1], m[2]], [m[4], m[5], m[6]], [m[8], m[9], m[10]]],
                t: [m[3], m[7], m[11]],
                fx: kk[0],
                fy: kk[4],
                cx: kk[2],
                cy: kk[5],
            }
        })
        .collect();
    Ok(render::Scene {
        poses: p,
        n,
        width: a.width,
        height: a.height,
        means,
        covs,
        frames,
        rigid,
        opacity,
        opacity_per_view,
        colors,
        cameras,
        views: a.views.clone(),
        cutoff: a.cutoff,
    })
}

/// Images and backward state: rgb `[V, H, W, 3]`, alpha, dsum `[V, H, W]`, contrib `[V, N]`.
fn render_outputs<'py, T: numpy::Element + Real>(
    py: Python<'py>,
    f: render::Forward<T>,
    wrap: fn(render::State<T>) -> AnyRenderState,
) -> PyResult<Bound<'py, PyTuple>> {
    let (v, n, h, w) = (f.state.scene.views.len(), f.state.scene.n, f.state.scene.height, f.state.scene.width);
    let items: Vec<Bound<'py, PyAny>> = vec![
        PyArray1::from_vec(py, f.rgb).reshape([v, h, w, 3])?.into_any(),
        PyArray1::from_vec(py, f.alpha).reshape([v, h, w])?.into_any(),
        PyArray1::from_vec(py, f.dsum).reshape([v, h, w])?.into_any(),
        PyArray1::from_vec(py, f.contrib).reshape([v, n])?.into_any(),
        f.npairs.into_pyobject(py)?.into_any(),
        Bound::new(py, PyRenderState { state: wrap(f.state) })?.into_any(),
    ];
    PyTuple::new(py, items)
}

/// The renderer after FK: projection, SH colour, rasterization (see `_core.pyi` and `render.rs`).
#[pyfunction]
#[pyo3(signature = (opacities, viewmats, Ks, views, width, height, *, means=None, covs=None, frames=None, body_rot=None,
                    body_pos=None, body=None, local_means=None, local_rots=None, local_quats=None, scales=None, colors=None, sh=None,
                    cutoff="soft", threads=None))]
#[allow(clippy::too_many_arguments)]
fn render_forward<'py>(
    py: Python<'py>,
    opacities: &Bound<'py, PyAny>,
    viewmats: &Bound<'py, PyAny>,
    #[allow(non_snake_case)] Ks: &Bound<'py, PyAny>,
    views: PyReadonlyArray2<'py, i64>,
    width: usize,
    height: usize,
    means: Option<&Bound<'py, PyAny>>,
    covs: Option<&Bound<'py, PyAny>>,
    frames: Option<&Bound<'py, PyAny>>,
    body_rot: Option<&Bound<'py, PyAny>>,
    body_pos: Option<&Bound<'py, PyAny>>,
    body: Option<&Bound<'py, PyAny>>,
    local_means: Option<&Bound<'py, PyAny>>,
    local_rots: Option<&Bound<'py, PyAny>>,
    local_quats: Option<&Bound<'py, PyAny>>,
    scales: Option<&Bound<'py, PyAny>>,
    colors: Option<&Bound<'py, PyAny>>,
    sh: Option<&Bound<'py, PyAny>>,
    cutoff: &str,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyTuple>> {
    let cutoff = match cutoff {
        "soft" => Cutoff::Soft,
        "hard" => Cutoff::Hard,
        other => return Err(input_error(format!("render_forward: cutoff must be 'soft' or 'hard'; got {other:?}"))),
    };
    if views.shape()[1] != 2 {
        return Err(input_error(format!("render_forward: views must have shape (V, 2); got {:?}", views.shape())));
    }
    let views: Vec<[usize; 2]> = views
        .as_array()
        .rows()
        .into_iter()
        .map(|r| if r[0] < 0 || r[1] < 0 { [usize::MAX, usize::MAX] } else { [r[0] as usize, r[1] as usize] })
        .collect();
    let world = match (means, covs) {
        (Some(m), Some(c)) => Some((m, c)),
        (None, None) => None,
        _ => return Err(input_error("render_forward: means= and covs= go together")),
    };
    let rots = match (local_rots, local_quats) {
        (Some(r), None) => Some(Rots::Matrices(r)),
        (None, Some(q)) => Some(Rots::Quats(q)),
        (None, None) => None,
        (Some(_), Some(_)) => return Err(input_error("render_forward: give local_rots= or local_quats=, not both")),
    };
    let rigid = match (body_rot, body_pos, body, local_means, scales, rots) {
        (Some(a), Some(b), Some(c), Some(d), Some(f), Some(e)) => Some(([a, b, c, d, f], e)),
        (None, None, None, None, None, None) => None,
        _ => {
            return Err(input_error(
                "render_forward: the rigid arrays body_rot=, body_pos=, body=, local_means=, local_rots= (or local_quats=), \
                 scales= go together",
            ))
        }
    };
    let args = SceneArgs { opacities, viewmats, ks: Ks, views, width, height, world, frames, rigid, colors, sh, cutoff };
    if dtype_of(opacities) == "float32" {
        let sc = read_scene::<f32>(&args, "float32")?;
        let f = py.detach(|| with_threads(threads, || render::forward(sc))).map_err(to_py)?.map_err(to_py)?;
        render_outputs(py, f, AnyRenderState::F32)
    } else {
        let sc = read_scene::<f64>(&args, "float64")?;
        let f = py.detach(|| with_threads(threads, || render::forward(sc))).map_err(to_py)?.map_err(to_py)?;
        render_outputs(py, f, AnyRenderState::F64)
    }
}

/// Gradients of one dtype, by input name (the rigid arrays' or the world ones').
#[allow(clippy::too_many_arguments)]
fn render_grads<'py, T: numpy::Element + Real>(
    py: Python<'py>,
    st: &render::State<T>,
    grad_rgb: &Bound<'py, PyAny>,
    grad_alpha: &Bound<'py, PyAny>,
    grad_dsum: &Bound<'py, PyAny>,
    needs: render::Needs,
    threads: Option<usize>,
    dtype: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &st.scene;
    let (v, n, h, w, p, c) = (s.views.len(), s.n, s.height, s.width, s.poses, s.cameras.len());
    // the upstream gradients are read in place when C-contiguous (a 256-view frame's are 75 MB)
    let img = |obj: &Bound<'py, PyAny>, name: &str, tail: &[usize]| -> PyResult<numpy::PyReadonlyArrayDyn<'py, T>> {
        let want: Vec<Option<usize>> = [v, h, w].iter().chain(tail).map(|&k| Some(k)).collect();
        real_view::<T>(obj, name, &want, dtype).map(|a| a.0).map_err(|e| {
            let msg = e.to_string().replace("render_forward", "render_backward");
            if e.is_instance_of::<PyTypeError>(py) {
                type_error(msg)
            } else {
                input_error(msg)
            }
        })
    };
    let (gr, ga, gd) = (img(grad_rgb, "grad_rgb", &[3])?, img(grad_alpha, "grad_alpha", &[])?, img(grad_dsum, "grad_dsum", &[])?);
    let (gr, ga, gd) = (rows_of(&gr), rows_of(&ga), rows_of(&gd));
    let (gr, ga, gd): (&[T], &[T], &[T]) = (&gr, &ga, &gd);
    let g = py.detach(|| with_threads(threads, || render::backward(st, gr, ga, gd, needs))).map_err(to_py)?.map_err(to_py)?;
    let out = PyDict::new(py);
    let colors = match &s.colors {
        _ if !needs.colors => None,
        render::Colors::Sh { nsh, .. } => Some(PyArray1::from_vec(py, g.colors).reshape([n, *nsh, 3])?.into_any()),
        render::Colors::Rgb { per_view: true, .. } => Some(PyArray1::from_vec(py, g.colors).reshape([v, n, 3])?.into_any()),
        render::Colors::Rgb { per_view: false, .. } => Some(PyArray1::from_vec(py, g.colors).reshape([n, 3])?.into_any()),
    };
    match g.rigid {
        None => {
            out.set_item("means", PyArray1::from_vec(py, g.means).reshape([p, n, 3])?)?;
            out.set_item("covs", PyArray1::from_vec(py, g.covs).reshape([p, n, 3, 3])?)?;
            if let Some(f) = g.frames {
                out.set_item("frames", PyArray1::from_vec(py, f).reshape([p, n, 3, 3])?)?;
            }
        }
        Some(r) => {
            let nb = s.rigid.as_ref().map_or(0, |r| r.nbody);
            out.set_item("body_rot", PyArray1::from_vec(py, r.body_rot).reshape([p, nb, 3, 3])?)?;
            out.set_item("body_pos", PyArray1::from_vec(py, r.body_pos).reshape([p, nb, 3])?)?;
            if needs.local {
                out.set_item("local_means", PyArray1::from_vec(py, r.means).reshape([n, 3])?)?;
                match s.rigid.as_ref().map(|r| &r.rots) {
                    Some(render::LocalRots::Quats(_)) => out.set_item("local_quats", PyArray1::from_vec(py, r.rots).reshape([n, 4])?)?,
                    _ => out.set_item("local_rots", PyArray1::from_vec(py, r.rots).reshape([n, 3, 3])?)?,
                }
                out.set_item("scales", PyArray1::from_vec(py, r.scales).reshape([n, 3])?)?;
            }
        }
    }
    if let Some(colors) = colors {
        out.set_item(if matches!(s.colors, render::Colors::Sh { .. }) { "sh" } else { "colors" }, colors)?;
    }
    if needs.opacity {
        let opacity = if s.opacity_per_view {
            PyArray1::from_vec(py, g.opacity).reshape([v, n])?.into_any()
        } else {
            PyArray1::from_vec(py, g.opacity).into_any()
        };
        out.set_item("opacities", opacity)?;
    }
    if needs.cameras {
        out.set_item("viewmats", PyArray1::from_vec(py, g.viewmats).reshape([c, 4, 4])?)?;
        out.set_item("Ks", PyArray1::from_vec(py, g.ks).reshape([c, 3, 3])?)?;
    }
    Ok(out)
}

/// The gradient groups `needs` names (None: all): any of `render_forward`'s array keywords.
fn needs_of(needs: Option<Vec<String>>) -> PyResult<render::Needs> {
    let Some(names) = needs else { return Ok(render::Needs::ALL) };
    let known = [
        "means",
        "covs",
        "frames",
        "body_rot",
        "body_pos",
        "body",
        "local_means",
        "local_rots",
        "local_quats",
        "scales",
        "colors",
        "sh",
        "opacities",
        "viewmats",
        "Ks",
    ];
    if let Some(bad) = names.iter().find(|k| !known.contains(&k.as_str())) {
        return Err(input_error(format!("render_backward: needs names {bad:?}, not one of render_forward's arrays {known:?}")));
    }
    let any = |ks: &[&str]| names.iter().any(|k| ks.contains(&k.as_str()));
    Ok(render::Needs {
        colors: any(&["colors", "sh"]),
        opacity: any(&["opacities"]),
        cameras: any(&["viewmats", "Ks"]),
        local: any(&["local_means", "local_rots", "local_quats", "scales"]),
    })
}

/// Gradients w.r.t. `render_forward`'s inputs (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (state, grad_rgb, grad_alpha, grad_dsum, *, needs=None, threads=None))]
#[allow(clippy::too_many_arguments)]
fn render_backward<'py>(
    py: Python<'py>,
    state: &PyRenderState,
    grad_rgb: &Bound<'py, PyAny>,
    grad_alpha: &Bound<'py, PyAny>,
    grad_dsum: &Bound<'py, PyAny>,
    needs: Option<Vec<String>>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let needs = needs_of(needs)?;
    match &state.state {
        AnyRenderState::F32(st) => render_grads(py, st, grad_rgb, grad_alpha, grad_dsum, needs, threads, "float32"),
        AnyRenderState::F64(st) => render_grads(py, st, grad_rgb, grad_alpha, grad_dsum, needs, threads, "float64"),
    }
}

/// `obj` as a `T` numpy array (a TypeError naming it otherwise), for the image functions.
fn image_array<'py, T: numpy::Element>(
    obj: &Bound<'py, PyAny>,
    who: &str,
    name: &str,
    dtype: &str,
) -> PyResult<numpy::PyReadonlyArrayDyn<'py, T>> {
    obj.extract().map_err(|_| {
        let got = obj.getattr("dtype").map(|d| d.to_string()).unwrap_or_else(|_| obj.get_type().to_string());
        type_error(format!("{who}: {name} must be a {dtype} numpy array, alpha's dtype (float32 or float64); got {got}"))
    })
}

/// Checks `got` against `want` (`[V, H, W]` then a tail), naming the array.
fn image_shape(who: &str, name: &str, got: &[usize], want: &[usize]) -> PyResult<()> {
    if got != want {
        return Err(input_error(format!("{who}: {name} must have shape {want:?}; got {got:?}")));
    }
    Ok(())
}

/// The `[V, H, W]` of `alpha`, the frame every other image array must match.
fn frame_of(who: &str, alpha: &numpy::PyReadonlyArrayDyn<'_, impl numpy::Element>) -> PyResult<[usize; 3]> {
    match *alpha.shape() {
        [v, h, w] => Ok([v, h, w]),
        ref s => Err(input_error(format!("{who}: alpha must have shape (V, H, W); got {s:?}"))),
    }
}

/// The optional background, `(3,)` or `(V, 3)`, as a row-major buffer.
fn background_arg<T: numpy::Element + Real>(bg: Option<&Bound<'_, PyAny>>, who: &str, v: usize, dtype: &str) -> PyResult<Option<Vec<T>>> {
    let Some(bg) = bg else { return Ok(None) };
    let a = image_array::<T>(bg, who, "background", dtype)?;
    if a.shape() != [3] && a.shape() != [v, 3] {
        return Err(input_error(format!("{who}: background must have shape (3,) or ({v}, 3); got {:?}", a.shape())));
    }
    let b = rows_of(&a).into_owned();
    if let Some(k) = b.iter().position(|x| !x.is_finite()) {
        return Err(input_error(format!("{who}: background[{k}] is {:?}", b[k].f64())));
    }
    Ok(Some(b))
}

/// The compute dtype the image functions take from `alpha`: float32, else float64 (any other
/// dtype then fails its read with a TypeError naming what it got).
fn dtype_of(obj: &Bound<'_, PyAny>) -> &'static str {
    match obj.getattr("dtype").and_then(|d| d.str()).map(|s| s.to_string()).as_deref() {
        Ok("float32") => "float32",
        _ => "float64",
    }
}

fn finish_t<T: numpy::Element + Real>(
    py: Python<'_>,
    rgb: &Bound<'_, PyAny>,
    alpha: &Bound<'_, PyAny>,
    dsum: &Bound<'_, PyAny>,
    background: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    dtype: &str,
) -> PyResult<()> {
    let who = "finish_images";
    let alpha = image_array::<T>(alpha, who, "alpha", dtype)?;
    let [v, h, w] = frame_of(who, &alpha)?;
    let bg = background_arg::<T>(background, who, v, dtype)?;
    let mut rgb: numpy::PyReadwriteArrayDyn<'_, T> =
        rgb.extract().map_err(|_| type_error(format!("{who}: rgb must be a writeable {dtype} numpy array, not borrowed elsewhere")))?;
    let mut dsum: numpy::PyReadwriteArrayDyn<'_, T> =
        dsum.extract().map_err(|_| type_error(format!("{who}: dsum must be a writeable {dtype} numpy array, not borrowed elsewhere")))?;
    image_shape(who, "rgb", rgb.shape(), &[v, h, w, 3])?;
    image_shape(who, "dsum", dsum.shape(), &[v, h, w])?;
    if !(rgb.is_c_contiguous() && dsum.is_c_contiguous()) {
        return Err(input_error(format!("{who}: rgb and dsum are finished in place and must be C-contiguous")));
    }
    let alpha = rows_of(&alpha);
    let (rgb, dsum) =
        (rgb.as_slice_mut().map_err(|e| input_error(e.to_string()))?, dsum.as_slice_mut().map_err(|e| input_error(e.to_string()))?);
    let alpha: &[T] = &alpha;
    py.detach(|| with_threads(threads, || images::finish(rgb, dsum, alpha, bg.as_deref(), v, h * w))).map_err(to_py)?.map_err(to_py)
}

/// Finishes rendered images in place: the background behind the robot, the expected depth
/// (see `_core.pyi` and `images.rs`).
#[pyfunction]
#[pyo3(signature = (rgb, alpha, dsum, *, background=None, threads=None))]
fn finish_images(
    py: Python<'_>,
    rgb: &Bound<'_, PyAny>,
    alpha: &Bound<'_, PyAny>,
    dsum: &Bound<'_, PyAny>,
    background: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
) -> PyResult<()> {
    match dtype_of(alpha) {
        "float32" => finish_t::<f32>(py, rgb, alpha, dsum, background, threads, "float32"),
        _ => finish_t::<f64>(py, rgb, alpha, dsum, background, threads, "float64"),
    }
}

type ImageGrads<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>);

#[allow(clippy::too_many_arguments)]
fn finish_backward_t<'py, T: numpy::Element + Real>(
    py: Python<'py>,
    grad_rgb: &Bound<'py, PyAny>,
    grad_alpha: &Bound<'py, PyAny>,
    grad_depth: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    background: Option<&Bound<'py, PyAny>>,
    threads: Option<usize>,
    dtype: &str,
) -> PyResult<ImageGrads<'py>> {
    let who = "finish_images_backward";
    let alpha = image_array::<T>(alpha, who, "alpha", dtype)?;
    let [v, h, w] = frame_of(who, &alpha)?;
    let bg = background_arg::<T>(background, who, v, dtype)?;
    let read = |obj: &Bound<'py, PyAny>, name: &str, tail: &[usize]| -> PyResult<numpy::PyReadonlyArrayDyn<'py, T>> {
        let a = image_array::<T>(obj, who, name, dtype)?;
        let want: Vec<usize> = [v, h, w].iter().chain(tail).copied().collect();
        image_shape(who, name, a.shape(), &want)?;
        Ok(a)
    };
    // the two gradients it rewrites are copies; grad_rgb, alpha and depth are read in place
    let mut g_alpha = rows_of(&read(grad_alpha, "grad_alpha", &[])?).into_owned();
    let mut g_depth = rows_of(&read(grad_depth, "grad_depth", &[])?).into_owned();
    let (g_rgb, depth) = (read(grad_rgb, "grad_rgb", &[3])?, read(depth, "depth", &[])?);
    let (g_rgb, depth, alpha) = (rows_of(&g_rgb), rows_of(&depth), rows_of(&alpha));
    let (g_rgb, depth, alpha): (&[T], &[T], &[T]) = (&g_rgb, &depth, &alpha);
    py.detach(|| {
        with_threads(threads, || images::finish_backward(g_rgb, &mut g_alpha, &mut g_depth, alpha, depth, bg.as_deref(), v, h * w))
    })
    .map_err(to_py)?
    .map_err(to_py)?;
    Ok((PyArray1::from_vec(py, g_alpha).reshape([v, h, w])?.into_any(), PyArray1::from_vec(py, g_depth).reshape([v, h, w])?.into_any()))
}

/// The gradient of [`finish_images`]: `(grad_alpha, grad_dsum)` w.r.t. the raw images.
#[pyfunction]
#[pyo3(signature = (grad_rgb, grad_alpha, grad_depth, alpha, depth, *, background=None, threads=None))]
#[allow(clippy::too_many_arguments)]
fn finish_images_backward<'py>(
    py: Python<'py>,
    grad_rgb: &Bound<'py, PyAny>,
    grad_alpha: &Bound<'py, PyAny>,
    grad_depth: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    background: Option<&Bound<'py, PyAny>>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyTuple>> {
    let (a, b) = match dtype_of(alpha) {
        "float32" => finish_backward_t::<f32>(py, grad_rgb, grad_alpha, grad_depth, alpha, depth, background, threads, "float32")?,
        _ => finish_backward_t::<f64>(py, grad_rgb, grad_alpha, grad_depth, alpha, depth, background, threads, "float64")?,
    };
    PyTuple::new(py, [a, b])
}

/// The image loss's arguments, read for one dtype (`images.rs`).
struct LossArgs<'a, 'py> {
    rgb: &'a Bound<'py, PyAny>,
    alpha: &'a Bound<'py, PyAny>,
    depth: &'a Bound<'py, PyAny>,
    rgb_t: &'a Bound<'py, PyAny>,
    depth_t: &'a Bound<'py, PyAny>,
    mask_t: &'a Bound<'py, PyAny>,
    valid: Option<&'a Bound<'py, PyAny>>,
    w_depth: f64,
    w_mask: f64,
    threads: Option<usize>,
}

/// The loss (`seed` None) or its gradient w.r.t. `(rgb, alpha, depth)` for the seeds `[V]`.
fn image_loss_t<'py, T: numpy::Element + Real>(
    py: Python<'py>,
    a: &LossArgs<'_, 'py>,
    seed: Option<&Bound<'py, PyAny>>,
    who: &str,
    dtype: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let alpha = image_array::<T>(a.alpha, who, "alpha", dtype)?;
    let [v, h, w] = frame_of(who, &alpha)?;
    let float = |obj: &Bound<'py, PyAny>, name: &str, tail: &[usize]| -> PyResult<numpy::PyReadonlyArrayDyn<'py, T>> {
        let x = image_array::<T>(obj, who, name, dtype)?;
        let want: Vec<usize> = [v, h, w].iter().chain(tail).copied().collect();
        image_shape(who, name, x.shape(), &want)?;
        Ok(x)
    };
    let boolean = |obj: &Bound<'py, PyAny>, name: &str| -> PyResult<numpy::PyReadonlyArrayDyn<'py, bool>> {
        let x: numpy::PyReadonlyArrayDyn<'py, bool> =
            obj.extract().map_err(|_| type_error(format!("{who}: {name} must be a bool numpy array")))?;
        image_shape(who, name, x.shape(), &[v, h, w])?;
        Ok(x)
    };
    let (rgb, depth, rgb_t, depth_t) =
        (float(a.rgb, "rgb", &[3])?, float(a.depth, "depth", &[])?, float(a.rgb_t, "rgb_t", &[3])?, float(a.depth_t, "depth_t", &[])?);
    let mask = boolean(a.mask_t, "mask_t")?;
    let valid = a.valid.map(|x| boolean(x, "valid")).transpose()?;
    let (rgb, alpha, depth, rgb_t, depth_t, mask) =
        (rows_of(&rgb), rows_of(&alpha), rows_of(&depth), rows_of(&rgb_t), rows_of(&depth_t), rows_of(&mask));
    let valid = valid.as_ref().map(|x| rows_of(x));
    let targets = images::LossTargets {
        rgb: &rgb_t,
        depth: &depth_t,
        mask: &mask,
        valid: valid.as_deref(),
        w_depth: T::c(a.w_depth),
        w_mask: T::c(a.w_mask),
    };
    let (rgb, alpha, depth): (&[T], &[T], &[T]) = (&rgb, &alpha, &depth);
    let threads = a.threads;
    match seed {
        None => {
            let loss = py
                .detach(|| with_threads(threads, || images::image_loss(rgb, alpha, depth, &targets, v, h * w)))
                .map_err(to_py)?
                .map_err(to_py)?;
            Ok(PyArray1::from_vec(py, loss).into_any())
        }
        Some(s) => {
            let s = image_array::<T>(s, who, "seed", dtype)?;
            image_shape(who, "seed", s.shape(), &[v])?;
            let s = rows_of(&s);
            let s: &[T] = &s;
            let (gr, ga, gd) = py
                .detach(|| with_threads(threads, || images::image_loss_backward(s, rgb, alpha, depth, &targets, v, h * w)))
                .map_err(to_py)?
                .map_err(to_py)?;
            let items = [
                PyArray1::from_vec(py, gr).reshape([v, h, w, 3])?.into_any(),
                PyArray1::from_vec(py, ga).reshape([v, h, w])?.into_any(),
                PyArray1::from_vec(py, gd).reshape([v, h, w])?.into_any(),
            ];
            Ok(PyTuple::new(py, items)?.into_any())
        }
    }
}

/// Per-image losses `(V,)` of finished renders against targets (see `_core.pyi`, `images.rs`).
#[pyfunction]
#[pyo3(signature = (rgb, alpha, depth, rgb_t, depth_t, mask_t, *, valid=None, w_depth=1.0, w_mask=0.5, threads=None))]
#[allow(clippy::too_many_arguments)]
fn image_loss<'py>(
    py: Python<'py>,
    rgb: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    rgb_t: &Bound<'py, PyAny>,
    depth_t: &Bound<'py, PyAny>,
    mask_t: &Bound<'py, PyAny>,
    valid: Option<&Bound<'py, PyAny>>,
    w_depth: f64,
    w_mask: f64,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let a = LossArgs { rgb, alpha, depth, rgb_t, depth_t, mask_t, valid, w_depth, w_mask, threads };
    match dtype_of(alpha) {
        "float32" => image_loss_t::<f32>(py, &a, None, "image_loss", "float32"),
        _ => image_loss_t::<f64>(py, &a, None, "image_loss", "float64"),
    }
}

/// The gradient of `sum(seed * image_loss(...))` w.r.t. `(rgb, alpha, depth)`.
#[pyfunction]
#[pyo3(signature = (seed, rgb, alpha, depth, rgb_t, depth_t, mask_t, *, valid=None, w_depth=1.0, w_mask=0.5, threads=None))]
#[allow(clippy::too_many_arguments)]
fn image_loss_backward<'py>(
    py: Python<'py>,
    seed: &Bound<'py, PyAny>,
    rgb: &Bound<'py, PyAny>,
    alpha: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    rgb_t: &Bound<'py, PyAny>,
    depth_t: &Bound<'py, PyAny>,
    mask_t: &Bound<'py, PyAny>,
    valid: Option<&Bound<'py, PyAny>>,
    w_depth: f64,
    w_mask: f64,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let a = LossArgs { rgb, alpha, depth, rgb_t, depth_t, mask_t, valid, w_depth, w_mask, threads };
    match dtype_of(alpha) {
        "float32" => image_loss_t::<f32>(py, &a, Some(seed), "image_loss_backward", "float32"),
        _ => image_loss_t::<f64>(py, &a, Some(seed), "image_loss_backward", "float64"),
    }
}

/// The extension's Rust allocations go through mimalloc (the interpreter's and numpy's do not):
/// freed blocks stay with the process for [`PURGE_DELAY_MS`] and the next call reuses them, where
/// glibc gives large blocks back to the OS at once and faults their pages in again on the next
/// call (measured: 26 000 page faults per render of 40 views, against 2 000-5 000).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc 3's `mi_option_purge_delay` (its `mimalloc.h` enum; the sys crate's table predates it).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Milliseconds freed memory stays committed before mimalloc gives it back to the OS. mimalloc's
/// 1 s counts from the first free of a region, so a stream of render calls (a pose fit: one
/// forward and backward every 20 ms-2 s) had its regions purged and faulted in again every
/// second: at 256 views a call, 2.4 ms of system time per view and 3.5 GiB purged in 17 calls;
/// 10 s: 0.7 ms and a per-view cost below a single pose's. The memory a large batch used (1.5 GiB
/// at 256 views) is held 10 s after its last use. `MIMALLOC_PURGE_DELAY` still overrides it.
const PURGE_DELAY_MS: std::os::raw::c_long = 10_000;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one integer option of this library's own allocator (thread-safe in
        // mimalloc; an option read concurrently sees the old or the new value).
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, PURGE_DELAY_MS) };
    }
    m.add_class::<PyRobotModel>()?;
    let py = m.py();
    let root = py.get_type::<ProfrobotError>();
    m.add("ProfrobotError", &root)?;
    let input = add_error_class(
        m,
        &INPUT_ERROR,
        "InputError",
        vec![root.clone(), py.get_type::<PyValueError>()],
        "Bad input: a shape, a NaN, an option out of range (a ValueError).",
    )?;
    add_error_class(
        m,
        &MODEL_ERROR,
        "ModelError",
        vec![input],
        "A robot model the core cannot label exactly (inconsistent arrays, unsupported geoms or joints).",
    )?;
    add_error_class(
        m,
        &INPUT_TYPE_ERROR,
        "InputTypeError",
        vec![root, py.get_type::<PyTypeError>()],
        "An argument of the wrong type or dtype (a TypeError).",
    )?;
    m.add_class::<PyRenderState>()?;
    m.add_function(wrap_pyfunction!(interpolate, m)?)?;
    m.add_function(wrap_pyfunction!(first_bad_entries, m)?)?;
    m.add_function(wrap_pyfunction!(voxel_downsample, m)?)?;
    m.add_function(wrap_pyfunction!(render_forward, m)?)?;
    m.add_function(wrap_pyfunction!(render_backward, m)?)?;
    m.add_function(wrap_pyfunction!(finish_images, m)?)?;
    m.add_function(wrap_pyfunction!(finish_images_backward, m)?)?;
    m.add_function(wrap_pyfunction!(image_loss, m)?)?;
    m.add_function(wrap_pyfunction!(image_loss_backward, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
