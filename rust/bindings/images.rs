//! Rendered images finished (background, expected depth) and compared (the image loss), with
//! their gradients.

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use super::arrays::{dtype_of, rows_of};
use super::errors::{input_error, to_py, type_error};
use crate::render::images;
use crate::render::real::Real;
use crate::threads::with_threads;

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
/// (see `_core.pyi` and `render/images.rs`).
#[pyfunction]
#[pyo3(signature = (rgb, alpha, dsum, *, background=None, threads=None))]
pub(super) fn finish_images(
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
pub(super) fn finish_images_backward<'py>(
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

/// The image loss's arguments, read for one dtype (`render/images.rs`).
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

/// Per-image losses `(V,)` of finished renders against targets (see `_core.pyi`, `render/images.rs`).
#[pyfunction]
#[pyo3(signature = (rgb, alpha, depth, rgb_t, depth_t, mask_t, *, valid=None, w_depth=1.0, w_mask=0.5, threads=None))]
#[allow(clippy::too_many_arguments)]
pub(super) fn image_loss<'py>(
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
pub(super) fn image_loss_backward<'py>(
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
