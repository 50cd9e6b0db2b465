//! `RobotModel`: the core's [`RobotModel`] built from MuJoCo's arrays, and its methods (labels,
//! certificates, motions, plans, inverse kinematics, sampling). pyo3 takes one `#[pymethods]` block
//! per class, so every method is here.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::conversion::FromPyObjectOwned;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyType};

use super::arrays::{pose_array, rows_of};
use super::clouds::{point_rows, radius_vec};
use super::errors::{input_error, model_error, to_py, type_error};
use super::interrupt;

use crate::collision::collide::{label_batch, LabelOptions};
use crate::collision::fastpath::{certified_batch, collides_batch, likely_pairs};
use crate::collision::filter::points_near_model;
use crate::ik::{ik, IkOptions, IkOutcome, IkTarget};
use crate::joints::couplings::Coupling;
use crate::joints::sample::sample_uniform;
use crate::model::desc::{CloudDesc, ModelDesc};
use crate::model::kinematics::{body_frames, forward_kinematics};
use crate::model::pairs::PairKind;
use crate::model::RobotModel;
use crate::planning::motion::prove_apart;
use crate::planning::motion::{certify_as_given, certify_blends, certify_motions, Motion, Order};
use crate::planning::oracle::{nearest_free, OracleOptions};
use crate::planning::plan::{plan_path, PlanOptions, PlanStatus};
use crate::planning::timing::time_path;
use crate::threads::with_threads;

/// A certificate's verdict as Python reads it: 0 certified, 1 blocked, 2 unproven.
fn motion_code(m: &Motion) -> u8 {
    match m {
        Motion::Certified => 0,
        Motion::Blocked(_) => 1,
        Motion::Unproven => 2,
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

/// `RobotModel.pairs()`: geom ids `(P, 2)`, is-self `(P,)`, margin `(P,)`.
type PairArrays<'py> = (Bound<'py, PyArray2<i32>>, Bound<'py, PyArray1<bool>>, Bound<'py, PyArray1<f64>>);

/// `RobotModel.body_frames()`: positions `(B, 3)`, quaternions `(B, 4)`.
type BodyFrames<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);
/// `RobotModel.forward_kinematics()`: xpos `(B, nbody, 3)`, xquat `(B, nbody, 4)`.
type FrameArrays<'py> = (Bound<'py, PyArray3<f64>>, Bound<'py, PyArray3<f64>>);

/// The compiled collision model of one robot scene (see `_core.pyi`): the core's
/// `RobotModel`, and the description it was built from, which is what pickles.
#[pyclass(name = "RobotModel", module = "profrobot._core", frozen)]
pub(super) struct PyRobotModel {
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
        let model = py.detach(|| self.model.rebuilt(&self.desc, desc.clone())).map_err(to_py)?;
        Ok(Self { model, desc })
    }

    /// The model of `arrays` (as `RobotModel(arrays)`), a scene edited from this one: geoms
    /// described bit for bit as one of this model's share its shape, and pairs of two such geoms
    /// their proofs (`RobotModel::rebuilt`), so replacing obstacles costs the new geoms, the
    /// candidate pairs, the broad phase and, on first use, the new pairs' proofs. Where the
    /// kinematics are this model's, its proofs are made first (once, `prove_apart`), and its
    /// likely pairs' sample drawn (`fastpath::likely_pairs`), for every model rebuilt from it to
    /// inherit; a model with other bodies (an object attached) inherits none, so none are made
    /// for it.
    fn rebuilt(&self, py: Python<'_>, arrays: &Bound<'_, PyDict>) -> PyResult<Self> {
        let desc = desc_from_dict(arrays)?;
        let model = py
            .detach(|| {
                if self.desc.same_kinematics(&desc) {
                    prove_apart(&self.model);
                    likely_pairs(&self.model);
                }
                self.model.rebuilt(&self.desc, desc.clone())
            })
            .map_err(to_py)?;
        Ok(Self { model, desc })
    }

    /// `(N,)` uint8 per point of `points` (N, 3, world metres) at `pose` (K,): 1 within `margin`
    /// metres of a robot geom, else 2 within `static_margin` of another geom (the point cloud
    /// excepted; `None`: not tested), else 0 (`collision/filter.rs`).
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

    /// Body `body`'s world frame at each pose: positions `(B, 3)`, quaternions `(B, 4)`
    /// `(w, x, y, z)` (`model/kinematics.rs`: its chain only).
    #[pyo3(signature = (poses, body, threads=None))]
    fn body_frames<'py>(
        &self,
        py: Python<'py>,
        poses: &Bound<'py, PyAny>,
        body: usize,
        threads: Option<usize>,
    ) -> PyResult<BodyFrames<'py>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let (xpos, xquat) = interrupt::run_batch(py, threads, q.len() / model.njoint().max(1), || body_frames(model, q, body))?;
        let b = xpos.len() / 3;
        Ok((PyArray1::from_vec(py, xpos).reshape([b, 3])?, PyArray1::from_vec(py, xquat).reshape([b, 4])?))
    }

    #[pyo3(signature = (poses, threads=None))]
    fn forward_kinematics<'py>(&self, py: Python<'py>, poses: &Bound<'py, PyAny>, threads: Option<usize>) -> PyResult<FrameArrays<'py>> {
        let model = &self.model;
        let poses = pose_array(poses, model.njoint(), "poses")?;
        let q = rows_of(&poses);
        let q: &[f64] = &q;
        let (xpos, xquat) = interrupt::run_batch(py, threads, q.len() / model.njoint().max(1), || forward_kinematics(model, q))?;
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
        let batch = interrupt::run_batch(py, threads, q.len() / model.njoint().max(1), || {
            // (checked first, so that bad input costs no proofs)
            model.check_poses(q)?;
            prove_apart(model);
            label_batch(model, q, opts)
        })?;
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
        let out = interrupt::run_batch(py, threads, q.len() / model.njoint().max(1), || {
            model.check_poses(q)?;
            prove_apart(model);
            collides_batch(model, q)
        })?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// Whether each pose is certified free at `clearance` metres (see `_core.pyi` and
    /// `collision/fastpath.rs`).
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
        let out = interrupt::run_batch(py, threads, q.len() / model.njoint().max(1), || {
            model.check_poses(q)?;
            crate::model::broad::check_clearance(clearance)?;
            prove_apart(model);
            certified_batch(model, q, clearance)
        })?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// The continuous certificate of each straight motion `starts[i] -> goals[i]`, or of each
    /// blend `starts[i] -> via[i] -> goals[i]` (see `_core.pyi` and `planning/motion.rs`).
    #[pyo3(signature = (starts, goals, clearance, *, via=None, as_given=false, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn certify_motions<'py>(
        &self,
        py: Python<'py>,
        starts: &Bound<'py, PyAny>,
        goals: &Bound<'py, PyAny>,
        clearance: f64,
        via: Option<&Bound<'py, PyAny>>,
        as_given: bool,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let (a, b) = (pose_array(starts, k, "starts")?, pose_array(goals, k, "goals")?);
        let (a, b) = (rows_of(&a), rows_of(&b));
        let (a, b): (&[f64], &[f64]) = (&a, &b);
        let v = via.map(|via| pose_array(via, k, "via")).transpose()?;
        let v = v.as_ref().map(rows_of);
        let v: Option<&[f64]> = v.as_deref();
        let r = match (v, as_given) {
            (_, true) => interrupt::run(py, threads, || certify_as_given(model, a, v, b, clearance, Order::EndFirst))?,
            (None, false) => interrupt::run(py, threads, || certify_motions(model, a, b, clearance))?,
            (Some(v), false) => interrupt::run(py, threads, || certify_blends(model, a, v, b, clearance))?,
        };
        let verdict: Vec<u8> = r.iter().map(|(m, _)| motion_code(m)).collect();
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

    /// `path` timed with its corners blended and cut where the certificate proves it (see
    /// `_core.pyi` and `planning/timing.rs`).
    #[pyo3(signature = (path, velocity, acceleration, clearance, *, blend=true, cut=0.5, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn time_path<'py>(
        &self,
        py: Python<'py>,
        path: &Bound<'py, PyAny>,
        velocity: PyReadonlyArray1<'py, f64>,
        acceleration: PyReadonlyArray1<'py, f64>,
        clearance: f64,
        blend: bool,
        cut: f64,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let w = pose_array(path, k, "path")?;
        let w = rows_of(&w);
        let (v, a) = (rows_of(&velocity), rows_of(&acceleration));
        let (w, v, a): (&[f64], &[f64], &[f64]) = (&w, &v, &a);
        let r = interrupt::run_here(py, threads, || time_path(model, w, v, a, blend, cut, clearance))?;
        let (m, p) = (r.times.len(), r.starts.len());
        let out = PyDict::new(py);
        out.set_item("waypoints", PyArray1::from_vec(py, r.waypoints).reshape([m, k])?)?;
        out.set_item("starts", PyArray1::from_vec(py, r.starts))?;
        out.set_item("q0", PyArray1::from_vec(py, r.q0).reshape([p, k])?)?;
        out.set_item("v0", PyArray1::from_vec(py, r.v0).reshape([p, k])?)?;
        out.set_item("acc", PyArray1::from_vec(py, r.acc).reshape([p, k])?)?;
        out.set_item("duration", r.duration)?;
        out.set_item("times", PyArray1::from_vec(py, r.times))?;
        out.set_item("stops", PyArray1::from_vec(py, r.stops))?;
        // (the first segment of the path whose crossed part is not certified, and its verdict)
        let (segment, verdict) = r.unproven.map_or((-1, 0), |(j, v)| (j as i64, motion_code(&v)));
        out.set_item("unproven_segment", segment)?;
        out.set_item("unproven_verdict", verdict)?;
        Ok(out)
    }

    /// The nearest free pose found for each pose (see `_core.pyi` and `planning/oracle.rs`).
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
        let r = interrupt::run(py, threads, || nearest_free(model, q, &opts))?;
        let b = r.distance.len();
        let out = PyDict::new(py);
        out.set_item("distance", PyArray1::from_vec(py, r.distance))?;
        out.set_item("poses", PyArray1::from_vec(py, r.poses).reshape([b, k])?)?;
        out.set_item("checks", PyArray1::from_iter(py, r.checks.iter().map(|&c| c as i64)))?;
        Ok(out)
    }

    /// A free path from `start` to `goal` (see `_core.pyi` and `planning/plan.rs`).
    #[pyo3(signature = (start, goal, *, resolution=0.01, max_time=10.0, seed=0, range=0.0, max_iterations=200_000, shortcut_rounds=200, verify=10, continuous=true, clearance=1e-6, held=None, threads=None))]
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
        held: Option<Vec<bool>>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let pose = |obj: &Bound<'py, PyAny>, what: &str| -> PyResult<Vec<f64>> {
            let a: PyReadonlyArray1<'py, f64> =
                obj.extract().map_err(|_| type_error(format!("{what} must be a 1-D float64 numpy array of shape (K,)")))?;
            Ok(a.as_array().to_vec())
        };
        let (s, g) = (pose(start, "start")?, pose(goal, "goal")?);
        let held = held.unwrap_or_default();
        let opts = PlanOptions { resolution, max_time, seed, range, max_iterations, shortcut_rounds, verify, continuous, clearance, held };
        let model = &self.model;
        let r = interrupt::run_here(py, threads, || plan_path(model, &s, &g, &opts))?;
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
        out.set_item("shortcut_seconds", r.shortcut_seconds)?;
        Ok(out)
    }

    /// Inverse kinematics of a frame (see `_core.pyi` and `ik/mod.rs`): `targets_pos` `(N, 3)`,
    /// `targets_quat` `(N, 4)` `(w, x, y, z)` or None (position only), `starts` `(N, K)`; the frame
    /// is body `body` offset by `local_pos`, `local_quat`.
    #[pyo3(signature = (targets_pos, targets_quat, starts, body, local_pos, local_quat, *, seeds=128, iterations=60, tol_pos=1e-6, tol_rot=1e-6, accept_pos=1e-6, accept_rot=1e-6, clearance=1e-6, seed=0, escape=true, held=None, moving=None, posture=None, free_axis=None, threads=None))]
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
        accept_pos: f64,
        accept_rot: f64,
        clearance: f64,
        seed: u64,
        escape: bool,
        held: Option<Vec<bool>>,
        moving: Option<Vec<bool>>,
        posture: Option<Vec<f64>>,
        free_axis: Option<[f64; 3]>,
        threads: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let model = &self.model;
        let k = model.njoint();
        let free_axis = match free_axis.map(Vector3::from) {
            Some(a) if !(a.norm() > 1e-9 && a.iter().all(|v| v.is_finite())) => {
                return Err(input_error(format!("free_axis must be a nonzero finite 3-vector; got {:?}", a.as_slice())));
            }
            a => a.map(|a| a.normalize()),
        };
        // joints held at their start values: a family's scene joints always, and those asked for
        let mut scene = self.desc.jnt_scene.clone();
        scene.resize(k, false); // (empty for a robot with no scene joints)
        if let Some(h) = held {
            if h.len() != k {
                return Err(input_error(format!("held has {} entries for {k} joints", h.len())));
            }
            scene.iter_mut().zip(&h).for_each(|(s, &h)| *s |= h);
        }
        if let Some(m) = &moving {
            if m.len() != k {
                return Err(input_error(format!("moving has {} entries for {k} joints", m.len())));
            }
        }
        if let Some(p) = &posture {
            if p.len() != k || !p.iter().all(|v| v.is_finite()) {
                return Err(input_error(format!("posture must be {k} finite joint values; got {p:?}")));
            }
        }
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
        let opts = IkOptions {
            body,
            local,
            seeds,
            iterations,
            tol_pos,
            tol_rot,
            accept_pos,
            accept_rot,
            free_axis,
            clearance,
            seed,
            escape,
            moving: moving.unwrap_or_default(),
            posture,
        };
        let scene: &[bool] = &scene;
        let r = interrupt::run(py, threads, || ik(model, &targets, starts, scene, &opts))?;
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
