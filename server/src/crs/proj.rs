//! The small safe layer over PROJ's C API (`proj-sys`) that [`super::Crs`] stands on.
//!
//! PROJ objects belong to the context they were made in, and a context must not be
//! used by two threads at once. So every thread has its own context, and its own
//! PROJ objects for the CRSs and transformations it has used, keyed by the CRS's
//! definition hash ([`super::Crs`] holds only plain data and is `Send + Sync`).
//! Transformations are `proj_create_crs_to_crs` (PROJ picks the best operation for
//! each point by area of use, datum-shift grids included when installed), normalised
//! to longitude/easting first, as GDAL's "traditional GIS order" and our
//! geotransforms are.
//!
//! This is the crate's one audited `unsafe` module: every block is a call into PROJ
//! with pointers this module made and owns, and each says why it is sound.
#![allow(unsafe_code)]

use proj_sys as sys;
use std::cell::RefCell;
use std::collections::HashMap;
use std::ffi::{CStr, CString, c_char};
use std::ptr;

/// Transformations a thread keeps (and twice as many CRSs) before it starts afresh.
const MAX_CACHED: usize = 256;

/// A PROJ object owned by this thread's context.
struct Object(*mut sys::PJ);

impl Drop for Object {
    fn drop(&mut self) {
        // SAFETY: the pointer came from PROJ, is non-null, and is destroyed once.
        unsafe { sys::proj_destroy(self.0) };
    }
}

/// This thread's context and the objects made in it. Objects are dropped before the
/// context (field order, and [`Drop`] below clears them first).
struct ThreadProj {
    crs: HashMap<u64, Object>,
    /// By (source, target, strict): strict operations refuse ballpark steps.
    operations: HashMap<(u64, u64, bool), Object>,
    ctx: *mut sys::PJ_CONTEXT,
}

impl ThreadProj {
    fn new() -> Self {
        // SAFETY: plain constructor; a null context would be an out-of-memory.
        let ctx = unsafe { sys::proj_context_create() };
        assert!(!ctx.is_null(), "PROJ could not create a context");
        // Errors are read back through proj_context_errno; PROJ's own stderr lines
        // would only repeat them.
        // SAFETY: ctx is a live context.
        unsafe { sys::proj_log_level(ctx, sys::PJ_LOG_LEVEL_PJ_LOG_NONE) };
        Self {
            crs: HashMap::new(),
            operations: HashMap::new(),
            ctx,
        }
    }

    /// The last error of this context, as PROJ words it.
    fn error(&self) -> String {
        // SAFETY: ctx is live; the string is PROJ's static or thread-local text.
        unsafe {
            let errno = sys::proj_context_errno(self.ctx);
            let text = sys::proj_context_errno_string(self.ctx, errno);
            string(text).unwrap_or_else(|| format!("PROJ error {errno}"))
        }
    }

    fn create(&self, definition: &str) -> Result<Object, String> {
        let c =
            CString::new(definition).map_err(|_| "the definition holds a NUL byte".to_string())?;
        // SAFETY: ctx is live and c a NUL-terminated string.
        let pj = unsafe { sys::proj_create(self.ctx, c.as_ptr()) };
        if pj.is_null() {
            return Err(self.error());
        }
        Ok(Object(pj))
    }

    fn crs(&mut self, id: u64, definition: &str) -> Result<*mut sys::PJ, String> {
        if let Some(o) = self.crs.get(&id) {
            return Ok(o.0);
        }
        let o = self.create(definition)?;
        let pj = o.0;
        self.crs.insert(id, o);
        Ok(pj)
    }

    fn operation(
        &mut self,
        from: (u64, &str),
        to: (u64, &str),
        strict: bool,
    ) -> Result<*mut sys::PJ, String> {
        if let Some(o) = self.operations.get(&(from.0, to.0, strict)) {
            return Ok(o.0);
        }
        // A build over thousands of inputs meets thousands of CRSs (each input's own
        // local projection for its ground spacing): start afresh rather than grow. No
        // object of this context is in use between calls.
        if self.operations.len() >= MAX_CACHED || self.crs.len() >= 2 * MAX_CACHED {
            self.operations.clear();
            self.crs.clear();
        }
        let src = self
            .crs(from.0, from.1)
            .map_err(|e| format!("source: {e}"))?;
        let dst = self.crs(to.0, to.1).map_err(|e| format!("target: {e}"))?;
        // Strict: no "ballpark" operation, which PROJ otherwise falls back to where a
        // grid is missing (EGM96 → EGM2008 heights without the EGM2008 grid would be
        // the identity, silently).
        let no_ballpark = CString::new("ALLOW_BALLPARK=NO").expect("no NUL");
        let options: [*const c_char; 2] = [no_ballpark.as_ptr(), ptr::null()];
        let options = if strict {
            options.as_ptr()
        } else {
            ptr::null()
        };
        // SAFETY: both CRSs are live objects of this context; `options` is null or a
        // null-terminated list of strings that outlive the call.
        let op = unsafe {
            sys::proj_create_crs_to_crs_from_pj(self.ctx, src, dst, ptr::null_mut(), options)
        };
        if op.is_null() {
            // SAFETY: ctx is live.
            return Err(if unsafe { sys::proj_context_errno(self.ctx) } == 0 {
                "PROJ finds no operation between them (a grid it needs may be missing)".into()
            } else {
                self.error()
            });
        }
        let op = Object(op);
        // SAFETY: op is a live operation of this context.
        if strict
            && unsafe { sys::proj_coordoperation_has_ballpark_transformation(self.ctx, op.0) } != 0
        {
            return Err(
                "PROJ has only a ballpark operation here (a grid it needs is missing)".into(),
            );
        }
        // SAFETY: op is live; the result is a new object (or null on error).
        let normalised = unsafe { sys::proj_normalize_for_visualization(self.ctx, op.0) };
        if normalised.is_null() {
            return Err(format!("normalising: {}", self.error()));
        }
        let normalised = Object(normalised);
        let pj = normalised.0;
        self.operations.insert((from.0, to.0, strict), normalised);
        Ok(pj)
    }
}

impl Drop for ThreadProj {
    fn drop(&mut self) {
        self.operations.clear();
        self.crs.clear();
        // SAFETY: every object of the context is gone; the context is destroyed once.
        unsafe { sys::proj_context_destroy(self.ctx) };
    }
}

thread_local! {
    static PROJ: RefCell<ThreadProj> = RefCell::new(ThreadProj::new());
}

/// A PROJ-owned C string, copied (`None` for null or non-UTF-8).
///
/// # Safety
/// `p` is null or a NUL-terminated string that lives for the call.
unsafe fn string(p: *const c_char) -> Option<String> {
    if p.is_null() {
        return None;
    }
    // SAFETY: the caller's contract.
    unsafe { CStr::from_ptr(p) }
        .to_str()
        .ok()
        .map(str::to_owned)
}

/// What PROJ says about a CRS definition, once, when a [`super::Crs`] is made.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Described {
    pub name: Option<String>,
    /// `AUTHORITY:CODE` of the CRS itself (`EPSG:2056`), or what PROJ identifies it
    /// as with full confidence.
    pub id: Option<(String, String)>,
    pub proj_string: Option<String>,
    /// WKT 1 as GDAL writes it, else WKT2:2019 (for CRSs WKT 1 cannot carry).
    pub wkt: Option<String>,
    /// Semi-axes of the ellipsoid of the CRS's geodetic datum.
    pub radii: Option<(f64, f64)>,
    pub celestial_body: Option<String>,
    pub geographic: bool,
    /// A compound (horizontal + vertical) CRS, or a 3-D geographic one: it says what
    /// heights are measured from.
    pub has_vertical: bool,
}

/// [`describe`], remembered process-wide: a collection of thousands of inputs names a
/// few CRSs thousands of times.
pub(super) fn describe_cached(definition: &str) -> Result<Described, String> {
    use std::sync::{Mutex, OnceLock};
    /// Definitions remembered; beyond this the memory starts afresh.
    const MAX: usize = 4096;
    static CACHE: OnceLock<Mutex<HashMap<String, Result<Described, String>>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Mutex::default);
    if let Some(d) = cache.lock().ok().and_then(|c| c.get(definition).cloned()) {
        return d;
    }
    let d = describe(definition);
    if let Ok(mut c) = cache.lock() {
        if c.len() >= MAX {
            c.clear();
        }
        c.insert(definition.to_string(), d.clone());
    }
    d
}

/// The [`Described`] of a definition PROJ accepts (`EPSG:CODE`, `EPSG:4326+5773`,
/// WKT 1 or 2, ESRI WKT, PROJJSON, a PROJ string); an error in PROJ's words for
/// anything else, and for objects that are not CRSs (a bare conversion or datum).
pub(super) fn describe(definition: &str) -> Result<Described, String> {
    PROJ.with_borrow(|p| {
        let o = p.create(definition)?;
        // SAFETY: o is a live object of p's context throughout.
        unsafe {
            if sys::proj_is_crs(o.0) == 0 {
                return Err("PROJ reads it, but as something other than a CRS".into());
            }
            // Objects looked at along the way, destroyed when this returns.
            let mut keep: Vec<Object> = Vec::new();
            let kind = sys::proj_get_type(o.0);
            let mut h = o.0;
            if kind == sys::PJ_TYPE_PJ_TYPE_COMPOUND_CRS {
                let sub = sys::proj_crs_get_sub_crs(p.ctx, o.0, 0);
                if !sub.is_null() {
                    keep.push(Object(sub));
                    h = sub;
                }
            }
            if sys::proj_get_type(h) == sys::PJ_TYPE_PJ_TYPE_BOUND_CRS {
                let base = sys::proj_get_source_crs(p.ctx, h);
                if !base.is_null() {
                    keep.push(Object(base));
                    h = base;
                }
            }
            let h_kind = sys::proj_get_type(h);
            let geographic = matches!(
                h_kind,
                sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_2D_CRS | sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_3D_CRS
            );
            let has_vertical = kind == sys::PJ_TYPE_PJ_TYPE_COMPOUND_CRS
                || kind == sys::PJ_TYPE_PJ_TYPE_GEOGRAPHIC_3D_CRS;
            // Identifying searches PROJ's database (~6 ms): only for WKT and PROJJSON,
            // which may spell out an EPSG CRS without its code; a PROJ string names
            // none, as gdalinfo reports it.
            let id = own_id(o.0).or_else(|| {
                (!definition.trim_start().starts_with('+'))
                    .then(|| identified(p, o.0))
                    .flatten()
            });
            let proj_string = string(sys::proj_as_proj_string(
                p.ctx,
                o.0,
                sys::PJ_PROJ_STRING_TYPE_PJ_PROJ_4,
                ptr::null(),
            ));
            let wkt = string(sys::proj_as_wkt(
                p.ctx,
                o.0,
                sys::PJ_WKT_TYPE_PJ_WKT1_GDAL,
                ptr::null(),
            ))
            .or_else(|| {
                string(sys::proj_as_wkt(
                    p.ctx,
                    o.0,
                    sys::PJ_WKT_TYPE_PJ_WKT2_2019,
                    ptr::null(),
                ))
            });
            let ellipsoid = Object(sys::proj_get_ellipsoid(p.ctx, h));
            let radii = (!ellipsoid.0.is_null())
                .then(|| {
                    let (mut a, mut b, mut computed, mut rf) = (0.0, 0.0, 0, 0.0);
                    (sys::proj_ellipsoid_get_parameters(
                        p.ctx,
                        ellipsoid.0,
                        &raw mut a,
                        &raw mut b,
                        &raw mut computed,
                        &raw mut rf,
                    ) != 0)
                        .then_some((a, b))
                })
                .flatten();
            let celestial_body = string(sys::proj_get_celestial_body_name(p.ctx, h));
            Ok(Described {
                name: string(sys::proj_get_name(o.0)),
                id,
                proj_string,
                wkt,
                radii,
                celestial_body,
                geographic,
                has_vertical,
            })
        }
    })
}

/// The object's own `AUTHORITY:CODE`, if it carries one.
///
/// # Safety
/// `o` is a live PROJ object.
unsafe fn own_id(o: *const sys::PJ) -> Option<(String, String)> {
    // SAFETY: the caller's contract; PROJ returns strings owned by `o`.
    unsafe {
        Some((
            string(sys::proj_get_id_auth_name(o, 0))?,
            string(sys::proj_get_id_code(o, 0))?,
        ))
    }
}

/// The EPSG CRS PROJ identifies `o` as with 100 % confidence (a WKT or PROJ string
/// that spells out an EPSG CRS without naming its code), as `gdalinfo` would name it.
///
/// # Safety
/// `o` is a live object of `p`'s context.
unsafe fn identified(p: &ThreadProj, o: *const sys::PJ) -> Option<(String, String)> {
    let epsg = CString::new("EPSG").expect("no NUL");
    let mut confidence: *mut std::ffi::c_int = ptr::null_mut();
    // SAFETY: the caller's contract; the list and confidences are freed below.
    unsafe {
        let list = sys::proj_identify(p.ctx, o, epsg.as_ptr(), ptr::null(), &raw mut confidence);
        if list.is_null() {
            return None;
        }
        let mut found = None;
        let n = sys::proj_list_get_count(list);
        for i in 0..n {
            if *confidence.add(i as usize) == 100 {
                let candidate = Object(sys::proj_list_get(p.ctx, list, i));
                if !candidate.0.is_null() {
                    found = own_id(candidate.0);
                }
                break;
            }
        }
        sys::proj_int_list_destroy(confidence);
        sys::proj_list_destroy(list);
        found
    }
}

/// Transforms `points` (x, y, z) in place from one CRS to another, with this thread's
/// cached operation. A point PROJ cannot transform becomes NaN; the error names the
/// first such point. `from`/`to` are `(definition hash, definition)`; `strict`
/// refuses ballpark operations.
pub(super) fn transform(
    from: (u64, &str),
    to: (u64, &str),
    points: &mut [[f64; 3]],
    strict: bool,
) -> Result<(), String> {
    PROJ.with_borrow_mut(|p| {
        let op = p.operation(from, to, strict)?;
        // Through a buffer on the stack, a chunk at a time: the one-point calls of the
        // approximate transformers (every tile plan, every reprojected row) allocate
        // nothing.
        let mut coords = [sys::PJ_COORD { v: [0.0; 4] }; CHUNK];
        let mut failed = None;
        for (k, chunk) in points.chunks_mut(CHUNK).enumerate() {
            for (c, &[x, y, z]) in coords.iter_mut().zip(chunk.iter()) {
                *c = sys::PJ_COORD {
                    v: [x, y, z, f64::INFINITY],
                };
            }
            // SAFETY: op is a live operation of this context; the first `chunk.len()`
            // of `coords` are initialised.
            unsafe {
                sys::proj_trans_array(
                    op,
                    sys::PJ_DIRECTION_PJ_FWD,
                    chunk.len(),
                    coords.as_mut_ptr(),
                )
            };
            for (i, (out, c)) in chunk.iter_mut().zip(&coords).enumerate() {
                // SAFETY: every PJ_COORD variant is four f64s.
                let v = unsafe { c.v };
                if v[..3].iter().all(|x| x.is_finite()) {
                    *out = [v[0], v[1], v[2]];
                } else {
                    failed.get_or_insert(k * CHUNK + i);
                    *out = [f64::NAN; 3];
                }
            }
        }
        match failed {
            None => Ok(()),
            Some(i) => Err(format!(
                "point {i} of {} cannot be transformed",
                points.len()
            )),
        }
    })
}

/// Points [`transform`] hands PROJ at a time, through a buffer on the stack.
const CHUNK: usize = 64;

/// PROJ's version, as the library in use reports it ("9.1.1").
pub fn version() -> String {
    // SAFETY: proj_info returns a struct of static strings.
    unsafe { string(sys::proj_info().version) }.unwrap_or_default()
}
