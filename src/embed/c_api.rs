//! The C ABI (docs/embedding.md "C"): opaque predictor handles, status codes, and the
//! last error's message per thread. `include/iastgcn.h` is generated from this file by
//! cbindgen (`make header`; tests/c_abi.rs fails when it is stale).
//!
//! Every function catches panics: none crosses the boundary, a caught one returns
//! [`IastgcnStatus::Panic`] with its message as the last error. Pointers are checked
//! for NULL; lengths are passed beside every array and checked against the model.

use super::{panic_message, Loaded};
use crate::error::{Error, Result};
use crate::model::{Backend, Features, Residual};
use std::cell::RefCell;
use std::ffi::{c_char, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

/// What a call returned. Negative values are failures; `iastgcn_last_error` then says
/// what went wrong.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IastgcnStatus {
    /// Success.
    Ok = 0,
    /// Fewer than T ticks have been pushed since the load or the last reset: there is no
    /// window to predict yet. Not a failure; nothing was written.
    NotReady = 1,
    /// A NULL pointer, a length that does not fit the model, or a value out of range.
    InvalidArgument = -1,
    /// The engine failed (a file it cannot read, a checkpoint it refuses, a device
    /// error).
    Error = -2,
    /// A bug in the engine: a panic, caught at the boundary. The handle should not be
    /// used again.
    Panic = -3,
}

/// Where a predictor runs its windows.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IastgcnBackend {
    /// The native CPU forward on the calling thread: needs no GPU driver. What a real-time
    /// controller should use.
    Native = 0,
    /// The default adapter (a Vulkan, Metal or DX12 GPU; `IASTGCN_ADAPTER` picks one by
    /// name); on a CPU adapter, the native forward.
    Auto = 1,
}

/// A loaded checkpoint ready to predict: create with `iastgcn_predictor_load`, free
/// with `iastgcn_predictor_free`. Not thread-safe: one thread at a time per handle.
pub struct IastgcnPredictor {
    loaded: Loaded,
    /// The graph's node names, NUL-terminated, in the frame's order.
    node_names: Vec<CString>,
    /// Reused by `iastgcn_predictor_predict_batch`.
    batch: Vec<Residual>,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    // An interior NUL cannot be represented; it is replaced.
    let text = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
}

/// A failure of the call: the status and the message for `iastgcn_last_error`.
struct Failure(IastgcnStatus, String);

impl From<Error> for Failure {
    fn from(e: Error) -> Failure {
        Failure(IastgcnStatus::Error, e.to_string())
    }
}

fn invalid(message: impl Into<String>) -> Failure {
    Failure(IastgcnStatus::InvalidArgument, message.into())
}

/// Runs `body` with panics caught and failures recorded as the thread's last error.
fn guard(body: impl FnOnce() -> Result<IastgcnStatus, Failure>) -> IastgcnStatus {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(status)) => status,
        Ok(Err(Failure(status, message))) => {
            set_last_error(&message);
            status
        }
        Err(panic) => {
            set_last_error(&panic_message(panic.as_ref()));
            IastgcnStatus::Panic
        }
    }
}

/// `len` values at `ptr`, or an invalid-argument failure naming `what`.
///
/// # Safety
/// `ptr` must be NULL or point at `len` readable values.
unsafe fn slice<'a, T>(ptr: *const T, len: usize, what: &str) -> Result<&'a [T], Failure> {
    if ptr.is_null() {
        return Err(invalid(format!("{what} is NULL")));
    }
    // SAFETY: not NULL, and the caller promises `len` readable values.
    Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
}

/// The handle behind `p`, or an invalid-argument failure.
///
/// # Safety
/// `p` must be NULL or a live handle from `iastgcn_predictor_load`.
unsafe fn handle<'a>(p: *mut IastgcnPredictor) -> Result<&'a mut IastgcnPredictor, Failure> {
    // SAFETY: the caller promises a live handle or NULL.
    unsafe { p.as_mut() }.ok_or_else(|| invalid("the predictor handle is NULL"))
}

/// Writes a residual to `out` (6 doubles).
///
/// # Safety
/// `out` must be NULL or point at 6 writable doubles.
unsafe fn write_residual(out: *mut f64, r: &Residual) -> Result<(), Failure> {
    if out.is_null() {
        return Err(invalid("out is NULL (it takes 6 doubles)"));
    }
    // SAFETY: not NULL, and the caller promises room for 6 doubles.
    unsafe { std::ptr::copy_nonoverlapping(r.as_ptr(), out, 6) };
    Ok(())
}

/// The engine's version ("0.1.0"), a static string.
#[no_mangle]
pub extern "C" fn iastgcn_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// The message of the last failed call on this thread ("" when none has failed). The
/// string stays valid until the next failing call on the same thread; copy it to keep
/// it. Thread-safe: each thread has its own.
#[no_mangle]
pub extern "C" fn iastgcn_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Loads the checkpoint at `path` (a `.safetensors` file written by iastgcn) and creates
/// a predictor in `*out`. `dt` is the control period in seconds of the recordings the
/// model was trained on (the twin's is 0.02): with `dt > 0` the handle takes raw sensor
/// values (`iastgcn_predictor_push`); with `dt == 0`, feature steps and windows only.
/// A `.toml` path is an ensemble file (its members' mean prediction and a calibrated
/// interval, `iastgcn_predictor_interval`); it needs `dt > 0`. All allocation and warm-up happen here; the per-tick calls allocate nothing.
/// Thread-safe (each call makes its own handle).
///
/// # Safety
/// `path` must be a NUL-terminated string and `out` a writable pointer; `*out` is set
/// to NULL on failure.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_load(
    path: *const c_char,
    dt: f64,
    backend: IastgcnBackend,
    out: *mut *mut IastgcnPredictor,
) -> IastgcnStatus {
    guard(|| {
        if out.is_null() {
            return Err(invalid("out is NULL"));
        }
        // SAFETY: not NULL; the caller promises it is writable.
        unsafe { *out = std::ptr::null_mut() };
        if path.is_null() {
            return Err(invalid("path is NULL"));
        }
        // SAFETY: not NULL; the caller promises a NUL-terminated string.
        let path = unsafe { CStr::from_ptr(path) }
            .to_str()
            .map_err(|_| invalid("path is not UTF-8"))?;
        if !(dt == 0.0 || dt.is_finite() && dt > 0.0) {
            return Err(invalid(format!(
                "dt: the control period is a positive number of seconds, or 0 for \
                 features only; got {dt}"
            )));
        }
        let dt = (dt > 0.0).then_some(dt);
        let loaded = Loaded::load(Path::new(path), dt, backend == IastgcnBackend::Native)?;
        let node_names = loaded
            .nodes()
            .iter()
            .map(|n| CString::new(n.replace('\0', "")).unwrap_or_default())
            .collect();
        let handle = Box::new(IastgcnPredictor {
            loaded,
            node_names,
            batch: Vec::new(),
        });
        // SAFETY: checked above.
        unsafe { *out = Box::into_raw(handle) };
        Ok(IastgcnStatus::Ok)
    })
}

/// Frees a handle from `iastgcn_predictor_load`; NULL is ignored.
///
/// # Safety
/// `p` must be NULL or a live handle, not used again afterwards.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_free(p: *mut IastgcnPredictor) {
    guard(|| {
        if !p.is_null() {
            // SAFETY: the caller gives back a handle from `Box::into_raw`.
            drop(unsafe { Box::from_raw(p) });
        }
        Ok(IastgcnStatus::Ok)
    });
}

/// The model's shape: graph nodes N, features per node F and window length T (ticks);
/// any pointer may be NULL. A sensor frame has N values, a feature step N·F floats, a
/// window N·F·T floats.
///
/// # Safety
/// `p` must be a live handle; the others NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_shape(
    p: *mut IastgcnPredictor,
    nodes: *mut usize,
    features: *mut usize,
    window: *mut usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        let c = h.loaded.predictor().config();
        for (ptr, v) in [(nodes, c.nodes), (features, c.features), (window, c.window)] {
            if !ptr.is_null() {
                // SAFETY: not NULL; the caller promises it is writable.
                unsafe { *ptr = v };
            }
        }
        Ok(IastgcnStatus::Ok)
    })
}

/// The tick the model's residual is for, in `*ticks`: 0 for the window's last tick (the
/// tick just pushed), 1 for the next, the tick a correction computed now acts on (a
/// look-ahead model, whose frame carries the controller's planned motion to that tick:
/// docs/embedding.md "Look-ahead models").
///
/// # Safety
/// `p` must be a live handle and `ticks` writable.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_look_ahead(
    p: *mut IastgcnPredictor,
    ticks: *mut usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        if ticks.is_null() {
            return Err(invalid("ticks is NULL"));
        }
        // SAFETY: not NULL; the caller promises it is writable.
        unsafe { *ticks = h.loaded.predictor().config().look_ahead };
        Ok(IastgcnStatus::Ok)
    })
}

/// The name of graph node `i` (the sensor channel the frame's i-th value comes from, e.g.
/// "T_ps"), or NULL when `i` is out of range. The string lives as long as the handle.
///
/// # Safety
/// `p` must be a live handle.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_node_name(
    p: *mut IastgcnPredictor,
    i: usize,
) -> *const c_char {
    let mut name = std::ptr::null();
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        name = h.node_names.get(i).map_or(std::ptr::null(), |n| n.as_ptr());
        Ok(IastgcnStatus::Ok)
    });
    name
}

/// Pushes one control tick of raw sensor values, `len` = N doubles in the node order of
/// `iastgcn_predictor_node_name`; NaN means "no new sample this tick" (the last one is
/// held). Needs a handle loaded with `dt > 0`. Allocation-free.
///
/// # Safety
/// `p` must be a live handle, `frame` point at `len` doubles.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_push(
    p: *mut IastgcnPredictor,
    frame: *const f64,
    len: usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle and `len` doubles.
        let (h, frame) = unsafe { (handle(p)?, slice(frame, len, "frame")?) };
        h.loaded.push(frame).map_err(|e| invalid(e.to_string()))?;
        Ok(IastgcnStatus::Ok)
    })
}

/// Pushes one step of per-node features (`len` = N·F floats, node-major, before
/// standardisation), for callers that compute the features themselves. Allocation-free.
///
/// # Safety
/// `p` must be a live handle, `step` point at `len` floats.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_push_features(
    p: *mut IastgcnPredictor,
    step: *const f32,
    len: usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle and `len` floats.
        let (h, step) = unsafe { (handle(p)?, slice(step, len, "step")?) };
        h.loaded
            .windows()
            .and_then(|p| p.push_step(step))
            .map_err(|e| invalid(e.to_string()))?;
        Ok(IastgcnStatus::Ok)
    })
}

/// The residual of the window ending at the last pushed tick, in `out[6]`: dx, dy, dz in
/// µm and rx, ry, rz in mdeg (base frame), the error to subtract from the next commanded
/// pose. Returns `IASTGCN_STATUS_NOT_READY` (and writes nothing) until T ticks have been
/// pushed. Allocation-free on the native backend.
///
/// # Safety
/// `p` must be a live handle, `out` point at 6 writable doubles.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_predict_latest(
    p: *mut IastgcnPredictor,
    out: *mut f64,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        if out.is_null() {
            return Err(invalid("out is NULL (it takes 6 doubles)"));
        }
        let latest = h.loaded.predict_latest().map_err(Error::from)?;
        match latest {
            Some(r) => {
                // SAFETY: not NULL; the caller promises 6 doubles.
                unsafe { write_residual(out, &r) }?;
                Ok(IastgcnStatus::Ok)
            }
            None => Ok(IastgcnStatus::NotReady),
        }
    })
}

/// The residual of one window of features (`len` = N·F·T floats, `[N, F, T]`, oldest
/// step first, before standardisation) in `out[6]`. Leaves the pushed ticks alone.
///
/// # Safety
/// `p` must be a live handle, `window` point at `len` floats, `out` at 6 doubles.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_predict(
    p: *mut IastgcnPredictor,
    window: *const f32,
    len: usize,
    out: *mut f64,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle and `len` floats.
        let (h, window) = unsafe { (handle(p)?, slice(window, len, "window")?) };
        let predictor = h.loaded.windows().map_err(|e| invalid(e.to_string()))?;
        if len != predictor.window_len() {
            return Err(invalid(format!(
                "window: expected N·F·T = {} floats, got {len}",
                predictor.window_len()
            )));
        }
        let r = predictor.predict(window).map_err(Error::from)?;
        // SAFETY: the caller promises 6 doubles.
        unsafe { write_residual(out, &r) }?;
        Ok(IastgcnStatus::Ok)
    })
}

/// The residuals of `len / (N·F·T)` windows `[W, N, F, T]` in `out` (`out_len` ≥ 6·W
/// doubles, window after window). Allocates on its first call for a batch size; for
/// offline use, not the control loop.
///
/// # Safety
/// `p` must be a live handle, `windows` point at `len` floats, `out` at `out_len`
/// doubles.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_predict_batch(
    p: *mut IastgcnPredictor,
    windows: *const f32,
    len: usize,
    out: *mut f64,
    out_len: usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle and `len` floats.
        let (h, windows) = unsafe { (handle(p)?, slice(windows, len, "windows")?) };
        let window = h.loaded.predictor().window_len();
        if !len.is_multiple_of(window) {
            return Err(invalid(format!(
                "windows: {len} floats is not a whole number of windows of N·F·T = {window}"
            )));
        }
        let needed = 6 * (len / window);
        if out.is_null() || out_len < needed {
            return Err(invalid(format!(
                "out: {} windows need {needed} doubles, got {}",
                len / window,
                if out.is_null() { 0 } else { out_len }
            )));
        }
        let mut batch = std::mem::take(&mut h.batch);
        let result = match h.loaded.windows() {
            Ok(p) => p
                .predict_batch(windows, Features::Raw, &mut batch)
                .map_err(Error::from)
                .map_err(Failure::from),
            Err(e) => Err(invalid(e.to_string())),
        };
        if result.is_ok() {
            for (k, r) in batch.iter().enumerate() {
                // SAFETY: out has room for 6 per window, checked above.
                unsafe { std::ptr::copy_nonoverlapping(r.as_ptr(), out.add(6 * k), 6) };
            }
        }
        h.batch = batch;
        result.map(|()| IastgcnStatus::Ok)
    })
}

/// The calibrated interval of the last prediction (docs/embedding.md "Ensembles and
/// intervals"): the true residual lies within `*position_um` of the predicted position
/// and within `*attitude_mdeg` of the predicted attitude (across the tool axis) with the
/// share `*level` on the session it was calibrated on. Only a handle loaded from an
/// ensemble file with an interval has one (`IASTGCN_STATUS_INVALID_ARGUMENT` otherwise);
/// `IASTGCN_STATUS_NOT_READY` (nothing written) before the first prediction. Any output
/// pointer may be NULL. Allocation-free.
///
/// # Safety
/// `p` must be a live handle; the others NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_interval(
    p: *mut IastgcnPredictor,
    position_um: *mut f64,
    attitude_mdeg: *mut f64,
    level: *mut f64,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        if h.loaded.interval_calibration().is_none() {
            return Err(invalid(
                "this handle has no calibrated interval: load an ensemble file with one \
                 (iastgcn confidence writes them)",
            ));
        }
        let Some(i) = h.loaded.interval() else {
            return Ok(IastgcnStatus::NotReady);
        };
        for (ptr, v) in [
            (position_um, i.position_um),
            (attitude_mdeg, i.attitude_mdeg),
            (level, i.level),
        ] {
            if !ptr.is_null() {
                // SAFETY: not NULL; the caller promises it is writable.
                unsafe { *ptr = v };
            }
        }
        Ok(IastgcnStatus::Ok)
    })
}

/// The checkpoints whose predictions the handle averages in `*members`: an ensemble
/// file's members, 1 for one checkpoint.
///
/// # Safety
/// `p` must be a live handle and `members` writable.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_members(
    p: *mut IastgcnPredictor,
    members: *mut usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        if members.is_null() {
            return Err(invalid("members is NULL"));
        }
        // SAFETY: not NULL; the caller promises it is writable.
        unsafe { *members = h.loaded.members() };
        Ok(IastgcnStatus::Ok)
    })
}

/// Forgets the pushed ticks and the features' filter state (a new run, or after a
/// pause in the trajectory).
///
/// # Safety
/// `p` must be a live handle.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_reset(p: *mut IastgcnPredictor) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        h.loaded.reset();
        Ok(IastgcnStatus::Ok)
    })
}

/// Splits each window of the native forward into `threads` tasks on a shared pool (1, the
/// default: the calling thread alone). The residuals do not depend on it.
///
/// # Safety
/// `p` must be a live handle.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_set_threads(
    p: *mut IastgcnPredictor,
    threads: usize,
) -> IastgcnStatus {
    guard(|| {
        // SAFETY: the caller promises a live handle.
        let h = unsafe { handle(p) }?;
        if threads == 0 {
            return Err(invalid("threads: 1 or more"));
        }
        h.loaded.set_threads(threads);
        Ok(IastgcnStatus::Ok)
    })
}

/// 1 when the handle runs on the native CPU forward, 0 on a device, -1 for NULL.
///
/// # Safety
/// `p` must be NULL or a live handle.
#[no_mangle]
pub unsafe extern "C" fn iastgcn_predictor_is_native(p: *mut IastgcnPredictor) -> i32 {
    let mut native = -1;
    guard(|| {
        // SAFETY: the caller promises a live handle or NULL.
        let h = unsafe { handle(p) }?;
        native = i32::from(h.loaded.predictor().backend() == Backend::Native);
        Ok(IastgcnStatus::Ok)
    });
    native
}
