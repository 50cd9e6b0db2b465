//! The renderer after forward kinematics: `render_forward`, `render_backward` and the state
//! between them.

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};

use super::arrays::{dtype_of, rows_of};
use super::errors::{input_error, to_py, type_error};
use crate::render;
use crate::render::real::Real;
use crate::render::splat::Cutoff;
use crate::threads::with_threads;

/// The backward state of one `render_forward` call (the scene, the tile lists and every
/// composited pair), in the dtype it was computed in; opaque to Python.
enum AnyRenderState {
    F32(render::State<f32>),
    F64(render::State<f64>),
}

#[pyclass(name = "RenderState", module = "profrobot._core", frozen)]
pub(super) struct PyRenderState {
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

/// The renderer after FK: projection, SH colour, rasterization (see `_core.pyi` and `render/mod.rs`).
#[pyfunction]
#[pyo3(signature = (opacities, viewmats, Ks, views, width, height, *, means=None, covs=None, frames=None, body_rot=None,
                    body_pos=None, body=None, local_means=None, local_rots=None, local_quats=None, scales=None, colors=None, sh=None,
                    cutoff="soft", threads=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn render_forward<'py>(
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
pub(super) fn render_backward<'py>(
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
