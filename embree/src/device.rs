//! A thin safe wrapper over `embree4-sys`: RAII device and triangle scenes, one padded ray-hit
//! structure, and Embree's error callback turned into our [`Error`].
//!
//! Two traps shape this file (see `/work/shared/notes` and ARCHITECTURE.md):
//!
//! - `embree4-sys` 0.0.12 ships the Embree **4.2** headers (an 80-byte `RTCRayHit`), while the
//!   4.4 release library is built with instance arrays and writes `hit.instPrimID[0]` at byte 80,
//!   4 bytes past the bindings' struct. Embree is therefore never handed a bare
//!   `sys::RTCRayHit`: [`RayHit`] pads it to 96 bytes, and [`Device::new`] traces one ray with
//!   poisoned padding and refuses a library that writes beyond 96 bytes.
//! - Without `RTC_SCENE_FLAG_ROBUST`, rays that pass exactly through shared triangle edges can
//!   slip through a closed mesh; scenes are robust unless asked otherwise.
//!
//! Only single rays (`rtcIntersect1`) are used, with NULL intersect arguments (Embree's
//! defaults; `rtcInitIntersectArguments` is an inline C function that bindgen cannot bind).

use embree4_sys as sys;
use std::cell::RefCell;
use std::ffi::{c_char, c_void, CStr, CString};
use tolray::error::{Error, ErrorKind, Result};

extern "C" {
    /// In the 4.4 library but not in the 4.2 headers of `embree4-sys`.
    fn rtcGetDeviceLastErrorMessage(device: sys::RTCDevice) -> *const c_char;
}

/// The callback type we register: the error code read as a plain `u32`, because the 4.4
/// library can report codes (7, `LEVEL_ZERO_RAYTRACING_SUPPORT_MISSING`) that the bindings'
/// Rust enum does not have.
type ErrorFn = unsafe extern "C" fn(*mut c_void, u32, *const c_char);

thread_local! {
    /// The first Embree error reported on this thread since the last [`take_error`].
    static LAST_ERROR: RefCell<Option<(u32, String)>> = const { RefCell::new(None) };
}

fn error_name(code: u32) -> &'static str {
    match code {
        0 => "no error",
        1 => "unknown error",
        2 => "invalid argument",
        3 => "invalid operation",
        4 => "out of memory",
        5 => "unsupported CPU",
        6 => "cancelled",
        7 => "Level Zero ray tracing support missing",
        _ => "unrecognized error code",
    }
}

/// Embree calls this on the thread whose API call failed.
unsafe extern "C" fn on_error(_user: *mut c_void, code: u32, msg: *const c_char) {
    let text = if msg.is_null() {
        String::new()
    } else {
        // SAFETY: Embree passes a NUL-terminated string valid for the duration of the call.
        unsafe { CStr::from_ptr(msg) }
            .to_string_lossy()
            .into_owned()
    };
    LAST_ERROR.with(|e| {
        let mut e = e.borrow_mut();
        if e.is_none() {
            *e = Some((code, text));
        }
    });
}

/// Takes the pending Embree error of this thread, if any, as our [`Error`] with `what` (the
/// operation) in the message.
fn take_error(what: &str) -> Result<()> {
    match LAST_ERROR.with(|e| e.borrow_mut().take()) {
        None => Ok(()),
        Some((code, text)) => Err(Error::new(
            ErrorKind::Numerical,
            format!("Embree: {what}: {} ({code}): {text}", error_name(code)),
        )),
    }
}

/// An Embree device (one per process is enough; [`Device::shared`] gives one). Embree's API is
/// thread-safe for distinct objects, so the device can be shared between threads.
pub struct Device {
    raw: sys::RTCDevice,
    version: u32,
}

// SAFETY: an RTCDevice may be used from any thread; Embree synchronizes internally.
unsafe impl Send for Device {}
// SAFETY: as above; every method takes `&self` and only calls thread-safe Embree functions.
unsafe impl Sync for Device {}

impl Device {
    /// Creates a device with an Embree configuration string (e.g. `""`, `"threads=1"`), installs
    /// the error callback, and runs the ray-hit layout self-test.
    ///
    /// # Errors
    /// [`ErrorKind::Invalid`] if the configuration holds a NUL byte; [`ErrorKind::Numerical`]
    /// with Embree's message if the device cannot be created, or if the library writes beyond the
    /// 96-byte [`RayHit`] (an Embree build with more than one instance level, which this wrapper
    /// does not support).
    pub fn new(config: &str) -> Result<Device> {
        let cfg = CString::new(config)
            .map_err(|_| Error::invalid("Embree device configuration contains a NUL byte"))?;
        // SAFETY: `cfg` is a valid NUL-terminated string for the duration of the call.
        let raw = unsafe { sys::rtcNewDevice(cfg.as_ptr()) };
        if raw.is_null() {
            // SAFETY: with a NULL device Embree reports the error of this thread's last call.
            let msg = unsafe { rtcGetDeviceLastErrorMessage(std::ptr::null_mut()) };
            let text = if msg.is_null() {
                String::from("no message")
            } else {
                // SAFETY: Embree returns a NUL-terminated string that lives until the next call.
                unsafe { CStr::from_ptr(msg) }
                    .to_string_lossy()
                    .into_owned()
            };
            return Err(Error::numerical(format!(
                "Embree: cannot create a device with configuration \"{config}\": {text}"
            )));
        }
        // SAFETY: RTCError is `#[repr(u32)]`, so a function taking a u32 in its place has the
        // same ABI; reading the code as u32 avoids an invalid enum value for new codes.
        let cb: sys::RTCErrorFunction = Some(unsafe {
            std::mem::transmute::<
                ErrorFn,
                unsafe extern "C" fn(*mut c_void, sys::RTCError, *const c_char),
            >(on_error)
        });
        // SAFETY: `raw` is a live device; the callback uses no user pointer.
        unsafe { sys::rtcSetDeviceErrorFunction(raw, cb, std::ptr::null_mut()) };
        // SAFETY: `raw` is a live device.
        let version =
            unsafe { sys::rtcGetDeviceProperty(raw, sys::RTCDeviceProperty::VERSION) } as u32;
        let dev = Device { raw, version };
        let written = dev.probe_layout()?;
        if let Some(&past) = written.iter().find(|&&b| b >= RayHit::SIZE) {
            return Err(Error::numerical(format!(
                "Embree {}: the library writes byte {past} of a ray hit, past the {} bytes this \
                 wrapper reserves (a build with EMBREE_MAX_INSTANCE_LEVEL_COUNT > 1?); use the \
                 Embree 4.4 release library",
                dev.version_string(),
                RayHit::SIZE
            )));
        }
        Ok(dev)
    }

    /// A process-wide device with the default configuration, created on first use.
    ///
    /// # Errors
    /// As [`Device::new`] (the same error is returned on every call).
    pub fn shared() -> Result<&'static Device> {
        static SHARED: std::sync::OnceLock<Result<Device>> = std::sync::OnceLock::new();
        SHARED
            .get_or_init(|| Device::new(""))
            .as_ref()
            .map_err(Clone::clone)
    }

    /// Embree's version as `10000 major + 100 minor + patch` (40400 for 4.4.0).
    pub fn version(&self) -> u32 {
        self.version
    }

    /// Embree's version as text, e.g. `4.4.0`.
    pub fn version_string(&self) -> String {
        let v = self.version;
        format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
    }

    /// Traces one ray at a one-triangle scene with the bytes after the bindings' 80-byte
    /// `RTCRayHit` poisoned (up to 64 bytes past the 96-byte [`RayHit`]), and returns the offsets
    /// of the bytes the library changed at or beyond byte 80. With the Embree 4.4 release library
    /// this is `80..84` (`instPrimID[0]`); with a 4.2/4.3 library it is empty.
    ///
    /// # Errors
    /// Embree errors while building the scene, or if the probe ray misses the triangle.
    pub fn probe_layout(&self) -> Result<Vec<usize>> {
        const POISON: u8 = 0xA5;
        #[repr(C, align(16))]
        struct Guarded {
            rh: RayHit,
            guard: [u8; 64],
        }
        let scene = Scene::new(
            self,
            &[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]],
            &[[0, 1, 2]],
            SceneOptions::default(),
        )?;
        let mut g = Guarded {
            rh: RayHit::new([0.0, 0.0, -1.0], [0.0, 0.0, 1.0], 0.0, f32::INFINITY),
            guard: [POISON; 64],
        };
        let base = std::ptr::addr_of_mut!(g) as *mut u8;
        // SAFETY: bytes 80..96 of `RayHit` are plain integer padding, and `guard` follows it;
        // every byte of `Guarded` from 80 on is ours to overwrite.
        unsafe { std::ptr::write_bytes(base.add(RAW_SIZE), POISON, RayHit::SIZE - RAW_SIZE) };
        scene.intersect_raw(&mut g.rh);
        if g.rh.rh.hit.geomID == sys::RTC_INVALID_GEOMETRY_ID {
            return Err(Error::numerical(
                "Embree: the layout probe ray missed its triangle",
            ));
        }
        let total = std::mem::size_of::<Guarded>();
        // SAFETY: reading the bytes of a live, fully initialized value.
        let bytes = unsafe { std::slice::from_raw_parts(base as *const u8, total) };
        Ok((RAW_SIZE..total).filter(|&i| bytes[i] != POISON).collect())
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: `raw` is a live device; scenes hold their own references.
        unsafe { sys::rtcReleaseDevice(self.raw) };
    }
}

/// Size of the bindings' (4.2) `RTCRayHit`, bytes.
const RAW_SIZE: usize = std::mem::size_of::<sys::RTCRayHit>();

/// A ray and its hit as Embree reads and writes them, padded past the 80-byte `RTCRayHit` of
/// the 4.2 headers to 96 bytes: the 4.4 library writes `hit.instPrimID[0]` at byte 80.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug)]
pub struct RayHit {
    /// The bindings' ray-hit structure (ray in, hit out).
    pub rh: sys::RTCRayHit,
    /// Where Embree 4.4 writes `hit.instPrimID[0]`.
    pub inst_prim_id: u32,
    _pad: [u32; 3],
}

const _: () = assert!(RAW_SIZE == 80 && std::mem::size_of::<RayHit>() == 96);

impl RayHit {
    /// Bytes reserved for Embree to write.
    pub const SIZE: usize = std::mem::size_of::<RayHit>();

    /// A ray from `org` along `dir` over `[tnear, tfar]`, with the hit fields initialized as
    /// Embree requires (geometry and instance ids invalid).
    pub fn new(org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32) -> RayHit {
        let inv = sys::RTC_INVALID_GEOMETRY_ID;
        RayHit {
            rh: sys::RTCRayHit {
                ray: sys::RTCRay {
                    org_x: org[0],
                    org_y: org[1],
                    org_z: org[2],
                    tnear,
                    dir_x: dir[0],
                    dir_y: dir[1],
                    dir_z: dir[2],
                    time: 0.0,
                    tfar,
                    mask: u32::MAX,
                    id: 0,
                    flags: 0,
                },
                hit: sys::RTCHit {
                    Ng_x: 0.0,
                    Ng_y: 0.0,
                    Ng_z: 0.0,
                    u: 0.0,
                    v: 0.0,
                    primID: inv,
                    geomID: inv,
                    instID: [inv],
                },
            },
            inst_prim_id: inv,
            _pad: [0; 3],
        }
    }
}

/// A hit reported by Embree.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter of the hit (distance along a unit direction), in the ray's units.
    pub t: f32,
    /// Triangle index.
    pub prim: u32,
    /// Barycentric coordinates: the hit is `(1 - u - v) v0 + u v1 + v v2`.
    pub u: f32,
    /// See `u`.
    pub v: f32,
    /// Unnormalized geometric normal `(v1 - v0) x (v2 - v0)` as Embree computed it.
    pub ng: [f32; 3],
}

/// How a scene is built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SceneOptions {
    /// `RTC_SCENE_FLAG_ROBUST`: watertight traversal, no leaks through shared edges.
    pub robust: bool,
    /// `RTC_BUILD_QUALITY_HIGH` instead of `MEDIUM` (a better BVH, a slower build).
    pub high_quality: bool,
}

impl Default for SceneOptions {
    /// Robust, medium build quality.
    fn default() -> Self {
        SceneOptions {
            robust: true,
            high_quality: false,
        }
    }
}

/// A committed scene holding one triangle mesh. Immutable after construction, so it can be
/// traced from several threads at once.
pub struct Scene {
    raw: sys::RTCScene,
    device: sys::RTCDevice,
}

// SAFETY: a committed scene is only read by rtcIntersect1, which Embree allows from any thread.
unsafe impl Send for Scene {}
// SAFETY: as above.
unsafe impl Sync for Scene {}

impl Scene {
    /// Builds and commits a scene of one triangle mesh: `vertices` (x, y, z) and `triangles`
    /// (three vertex indices each).
    ///
    /// # Errors
    /// [`ErrorKind::Argument`] for an empty mesh or an index out of range;
    /// [`ErrorKind::Numerical`] with Embree's message when Embree fails (e.g. out of memory).
    pub fn new(
        device: &Device,
        vertices: &[[f32; 3]],
        triangles: &[[u32; 3]],
        opts: SceneOptions,
    ) -> Result<Scene> {
        if vertices.is_empty() || triangles.is_empty() {
            return Err(Error::argument("Embree scene: empty triangle mesh"));
        }
        let nv = vertices.len();
        if let Some(t) = triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= nv))
        {
            return Err(Error::argument(format!(
                "Embree scene: triangle {t:?} indexes past the {nv} vertices"
            )));
        }
        take_error("before building a scene").ok();
        // SAFETY: `device.raw` is a live device.
        let raw = unsafe { sys::rtcNewScene(device.raw) };
        take_error("rtcNewScene")?;
        if raw.is_null() {
            return Err(Error::numerical("Embree: rtcNewScene returned NULL"));
        }
        // SAFETY: `device.raw` is live; the reference is released when the scene drops, so the
        // device outlives every scene even if the `Device` value is dropped first.
        unsafe { sys::rtcRetainDevice(device.raw) };
        let scene = Scene {
            raw,
            device: device.raw,
        };
        let mut flags = sys::RTCSceneFlags::NONE;
        if opts.robust {
            flags |= sys::RTCSceneFlags::ROBUST;
        }
        let quality = if opts.high_quality {
            sys::RTCBuildQuality::HIGH
        } else {
            sys::RTCBuildQuality::MEDIUM
        };
        // SAFETY: `scene.raw` is a live scene (released by Drop on every path below).
        unsafe {
            sys::rtcSetSceneFlags(scene.raw, flags);
            sys::rtcSetSceneBuildQuality(scene.raw, quality);
        }
        // SAFETY: `device.raw` is a live device.
        let geom = unsafe { sys::rtcNewGeometry(device.raw, sys::RTCGeometryType::TRIANGLE) };
        take_error("rtcNewGeometry")?;
        if geom.is_null() {
            return Err(Error::numerical("Embree: rtcNewGeometry returned NULL"));
        }
        let geom = Geometry(geom);
        // SAFETY: `geom` is live; Embree allocates buffers of the given item count and stride
        // (with its own tail padding) and returns them, or NULL with an error.
        let (vbuf, ibuf) = unsafe {
            let v = sys::rtcSetNewGeometryBuffer(
                geom.0,
                sys::RTCBufferType::VERTEX,
                0,
                sys::RTCFormat::FLOAT3,
                12,
                nv,
            ) as *mut [f32; 3];
            let i = sys::rtcSetNewGeometryBuffer(
                geom.0,
                sys::RTCBufferType::INDEX,
                0,
                sys::RTCFormat::UINT3,
                12,
                triangles.len(),
            ) as *mut [u32; 3];
            (v, i)
        };
        take_error("rtcSetNewGeometryBuffer")?;
        if vbuf.is_null() || ibuf.is_null() {
            return Err(Error::numerical(
                "Embree: rtcSetNewGeometryBuffer returned NULL",
            ));
        }
        // SAFETY: the buffers hold `nv` and `triangles.len()` items of 12 bytes, 4-aligned.
        unsafe {
            std::ptr::copy_nonoverlapping(vertices.as_ptr(), vbuf, nv);
            std::ptr::copy_nonoverlapping(triangles.as_ptr(), ibuf, triangles.len());
            sys::rtcCommitGeometry(geom.0);
        }
        take_error("rtcCommitGeometry")?;
        // SAFETY: both objects are live; the scene takes its own reference to the geometry.
        unsafe { sys::rtcAttachGeometry(scene.raw, geom.0) };
        take_error("rtcAttachGeometry")?;
        drop(geom);
        // SAFETY: `scene.raw` is live and not yet shared with other threads.
        unsafe { sys::rtcCommitScene(scene.raw) };
        take_error("rtcCommitScene")?;
        Ok(scene)
    }

    /// Traces `rh` (in: ray; out: `tfar` and the hit) with `rtcIntersect1`.
    pub fn intersect_raw(&self, rh: &mut RayHit) {
        // SAFETY: `rh` is a 96-byte RayHit, which covers everything the 4.2-4.4 libraries
        // write (checked at device creation); NULL arguments select Embree's defaults.
        unsafe {
            sys::rtcIntersect1(
                self.raw,
                std::ptr::addr_of_mut!(rh.rh),
                std::ptr::null_mut(),
            )
        };
    }

    /// The first hit of the ray `org + t dir` with `t` in `[tnear, tfar]`, or `None`.
    pub fn intersect(&self, org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32) -> Option<Hit> {
        let mut rh = RayHit::new(org, dir, tnear, tfar);
        self.intersect_raw(&mut rh);
        let h = &rh.rh.hit;
        (h.geomID != sys::RTC_INVALID_GEOMETRY_ID).then_some(Hit {
            t: rh.rh.ray.tfar,
            prim: h.primID,
            u: h.u,
            v: h.v,
            ng: [h.Ng_x, h.Ng_y, h.Ng_z],
        })
    }
}

impl Drop for Scene {
    fn drop(&mut self) {
        // SAFETY: `raw` is a live scene owned by this value, `device` the reference it took.
        unsafe {
            sys::rtcReleaseScene(self.raw);
            sys::rtcReleaseDevice(self.device);
        }
    }
}

/// A geometry handle released on drop (the scene keeps its own reference once attached).
struct Geometry(sys::RTCGeometry);

impl Drop for Geometry {
    fn drop(&mut self) {
        // SAFETY: a live geometry owned by this value.
        unsafe { sys::rtcReleaseGeometry(self.0) };
    }
}
