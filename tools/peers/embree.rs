//! Embree 4 (Intel's CPU ray tracing kernels) as a peer, behind the cargo feature `embree`.
//!
//! A hand-written binding of the dozen functions used, linked against the `libembree4` of the
//! `embreex` wheel (`tools/embree.sh` fetches it, `build.rs` passes its directory to the linker).
//! Every declaration below was copied from Embree 4.4.0's headers (`include/embree4/rtcore_*.h`,
//! tag `v4.4.0`); the file names each comes from. All `unsafe` of the peers lives in this file.
//!
//! # Configuration
//!
//! [`SCENE_FLAGS`] `RTC_SCENE_FLAG_NONE` and [`BUILD_QUALITY`] `RTC_BUILD_QUALITY_HIGH`: one
//! triangle geometry, the fastest configuration Embree offers for a static scene (in 4.4.0,
//! `Scene::createTriangleAccel` picks a BVH8 of `Triangle4` with spatial splits on an AVX
//! machine, a BVH4 otherwise, and the Möller–Trumbore intersector). `RTC_SCENE_FLAG_ROBUST` would
//! switch to the watertight Plücker test and conservative box tests, but it also ignores the
//! build quality (it always builds `BuildVariant::STATIC`), so it would not be Embree at its best.
//! Embree picks its ISA (SSE2 to AVX-512) at run time; oavm is compiled for x86-64-v2.
//!
//! # Answers as `../shared/RAYS.md` asks
//!
//! - Direction as given: Embree never normalises it, and its `t` is in units of the direction.
//! - Embree's segment must lie in `[0, inf]` (`rtcIntersect1.md`: "ranges that start behind the
//!   ray origin are not valid"; the traversal clamps `tnear` to 0 and debug builds assert it).
//!   A ray with `tmin >= 0` is given as is; a ray with `tmin < 0` is traced from the point at
//!   `tmin` over `[0, tmax - tmin]` and its `t` shifted back by `tmin`, which costs one rounding
//!   of the origin.
//! - Inclusive ends: Embree's Möller test accepts `tnear < t <= tfar`
//!   (`kernels/geometry/triangle_intersector_moeller.h`), and its documentation guarantees
//!   neither end. `tnear` is passed one ulp below `tmin`, so a hit at exactly `tmin` counts
//!   (except `tmin = 0`, which cannot go lower: a hit at exactly `t = 0`, the origin on a
//!   triangle, may be missed); a reported `t` is clamped into `[tmin, tmax]`. This is as close
//!   as one query per ray gets: the test compares in scaled units (`absDen * tnear < T`,
//!   `T <= absDen * tfar`) and reports `t = T / absDen`, so a hit whose reported `t` is exactly
//!   `tmin` or `tmax` may still be lost when re-traced with that end (`peers_smoke` counts them;
//!   on the bunny about one in seven). Benchmark rays never have a hit at an end (`tmin` is 0 or
//!   an offset, `tmax` infinite or at the light), and on every ray set of `peers_smoke` Embree
//!   agrees with brute force.
//! - Invalid rays ([`Ray::is_valid`]) miss without reaching Embree.
//! - `prim` is Embree's `primID`, the triangle's index in the index buffer, which is the order of
//!   the `triangles` given to [`EmbreeScene::build`]; degenerate triangles keep their index and
//!   are never hit.
//!
//! The hit's `t` is the ray's `tfar` after `rtcIntersect1` (Embree writes it there); a hit is
//! recognised by `geomID != RTC_INVALID_GEOMETRY_ID`. `rtcOccluded1` marks an occluded ray by
//! setting `tfar` to `-inf`.

use std::ffi::{CStr, c_char, c_int, c_uint, c_void};

use oavm::{Hit, Ray};

/// What the benchmark prints: the configuration [`EmbreeScene::build`] uses.
pub const SCENE_FLAGS: &str = "RTC_SCENE_FLAG_NONE";
pub const BUILD_QUALITY: &str = "RTC_BUILD_QUALITY_HIGH";

mod ffi {
    use super::*;

    // rtcore_device.h, rtcore_scene.h, rtcore_geometry.h: opaque handles.
    #[repr(C)]
    pub struct RTCDeviceTy {
        _opaque: [u8; 0],
    }
    #[repr(C)]
    pub struct RTCSceneTy {
        _opaque: [u8; 0],
    }
    #[repr(C)]
    pub struct RTCGeometryTy {
        _opaque: [u8; 0],
    }
    pub type RTCDevice = *mut RTCDeviceTy;
    pub type RTCScene = *mut RTCSceneTy;
    pub type RTCGeometry = *mut RTCGeometryTy;

    // C enums are `int`-sized; only the values used are declared.

    /// rtcore_device.h, `enum RTCDeviceProperty`.
    pub const RTC_DEVICE_PROPERTY_VERSION: c_int = 0;
    pub const RTC_DEVICE_PROPERTY_BACKFACE_CULLING_ENABLED: c_int = 65;
    pub const RTC_DEVICE_PROPERTY_TASKING_SYSTEM: c_int = 128;
    /// rtcore_device.h, `enum RTCError`.
    pub const RTC_ERROR_NONE: c_int = 0;
    /// rtcore_scene.h, `enum RTCSceneFlags`.
    pub const RTC_SCENE_FLAG_NONE: c_int = 0;
    /// rtcore_common.h, `enum RTCBuildQuality`.
    pub const RTC_BUILD_QUALITY_HIGH: c_int = 2;
    /// rtcore_geometry.h, `enum RTCGeometryType`.
    pub const RTC_GEOMETRY_TYPE_TRIANGLE: c_int = 0;
    /// rtcore_buffer.h, `enum RTCBufferType`.
    pub const RTC_BUFFER_TYPE_INDEX: c_int = 0;
    pub const RTC_BUFFER_TYPE_VERTEX: c_int = 1;
    /// rtcore_common.h, `enum RTCFormat`.
    pub const RTC_FORMAT_UINT3: c_int = 0x5003;
    pub const RTC_FORMAT_FLOAT3: c_int = 0x9003;
    /// rtcore_common.h, `RTC_INVALID_GEOMETRY_ID`.
    pub const RTC_INVALID_GEOMETRY_ID: c_uint = c_uint::MAX;

    /// rtcore_ray.h, `struct RTC_ALIGN(16) RTCRay`.
    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    pub struct RTCRay {
        pub org_x: f32,
        pub org_y: f32,
        pub org_z: f32,
        pub tnear: f32,
        pub dir_x: f32,
        pub dir_y: f32,
        pub dir_z: f32,
        pub time: f32,
        pub tfar: f32,
        pub mask: c_uint,
        pub id: c_uint,
        pub flags: c_uint,
    }

    /// rtcore_ray.h, `struct RTC_ALIGN(16) RTCHit`, for the release configuration of 4.4.0
    /// (`RTC_MAX_INSTANCE_LEVEL_COUNT` = 1, `RTC_GEOMETRY_INSTANCE_ARRAY` defined: CMake's
    /// defaults, which the release presets keep). Without the instance-array field the C struct
    /// would be 32 bytes; with it, 48, so this layout is also large enough for a library built
    /// without it.
    #[repr(C, align(16))]
    #[derive(Clone, Copy)]
    pub struct RTCHit {
        pub ng_x: f32,
        pub ng_y: f32,
        pub ng_z: f32,
        pub u: f32,
        pub v: f32,
        pub prim_id: c_uint,
        pub geom_id: c_uint,
        pub inst_id: [c_uint; 1],
        pub inst_prim_id: [c_uint; 1],
    }

    /// rtcore_ray.h, `struct RTCRayHit`.
    #[repr(C)]
    #[derive(Clone, Copy)]
    pub struct RTCRayHit {
        pub ray: RTCRay,
        pub hit: RTCHit,
    }

    // The C layouts, checked at compile time.
    const _: () = {
        use std::mem::{align_of, offset_of, size_of};
        assert!(size_of::<RTCRay>() == 48 && align_of::<RTCRay>() == 16);
        assert!(offset_of!(RTCRay, tnear) == 12 && offset_of!(RTCRay, tfar) == 32);
        assert!(offset_of!(RTCRay, flags) == 44);
        assert!(size_of::<RTCHit>() == 48 && align_of::<RTCHit>() == 16);
        assert!(offset_of!(RTCHit, prim_id) == 20 && offset_of!(RTCHit, geom_id) == 24);
        assert!(size_of::<RTCRayHit>() == 96 && offset_of!(RTCRayHit, hit) == 48);
    };

    #[link(name = "embree4")]
    unsafe extern "C" {
        // rtcore_device.h
        pub fn rtcNewDevice(config: *const c_char) -> RTCDevice;
        pub fn rtcReleaseDevice(device: RTCDevice);
        pub fn rtcGetDeviceProperty(device: RTCDevice, prop: c_int) -> isize;
        pub fn rtcGetDeviceError(device: RTCDevice) -> c_int;
        pub fn rtcGetDeviceLastErrorMessage(device: RTCDevice) -> *const c_char;
        pub fn rtcGetErrorString(error: c_int) -> *const c_char;
        // rtcore_scene.h
        pub fn rtcNewScene(device: RTCDevice) -> RTCScene;
        pub fn rtcReleaseScene(scene: RTCScene);
        pub fn rtcSetSceneFlags(scene: RTCScene, flags: c_int);
        pub fn rtcSetSceneBuildQuality(scene: RTCScene, quality: c_int);
        pub fn rtcAttachGeometry(scene: RTCScene, geometry: RTCGeometry) -> c_uint;
        pub fn rtcCommitScene(scene: RTCScene);
        pub fn rtcIntersect1(scene: RTCScene, rayhit: *mut RTCRayHit, args: *mut c_void);
        pub fn rtcOccluded1(scene: RTCScene, ray: *mut RTCRay, args: *mut c_void);
        // rtcore_geometry.h
        pub fn rtcNewGeometry(device: RTCDevice, kind: c_int) -> RTCGeometry;
        pub fn rtcReleaseGeometry(geometry: RTCGeometry);
        pub fn rtcCommitGeometry(geometry: RTCGeometry);
        pub fn rtcSetGeometryBuildQuality(geometry: RTCGeometry, quality: c_int);
        pub fn rtcSetNewGeometryBuffer(
            geometry: RTCGeometry,
            kind: c_int,
            slot: c_uint,
            format: c_int,
            byte_stride: usize,
            item_count: usize,
        ) -> *mut c_void;
    }
}

use ffi::*;

/// A committed Embree scene holding one triangle geometry.
pub struct EmbreeScene {
    device: RTCDevice,
    scene: RTCScene,
}

// SAFETY: the handles are reference-counted pointers owned by this value alone. Embree documents
// a committed scene as read-only for queries: `rtcIntersect1`/`rtcOccluded1` may be called from
// any number of threads at once (they write only to the caller's ray), and nothing here changes
// the scene after `build` commits it. Dropping (releasing) needs `&mut self`, so it cannot race
// with queries.
unsafe impl Send for EmbreeScene {}
// SAFETY: as for `Send`: after commit, every `&self` method is a thread-safe Embree query.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds the scene: one triangle geometry over copies of `positions` and `triangles`
    /// (Embree-owned buffers, which carry the padding Embree's vector loads need), scene flags
    /// [`SCENE_FLAGS`], build quality [`BUILD_QUALITY`], committed with Embree's own threads.
    ///
    /// # Panics
    /// If Embree reports an error (the message is Embree's), or a vertex index is out of range.
    pub fn build(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        assert!(
            triangles
                .iter()
                .flatten()
                .all(|&v| (v as usize) < positions.len()),
            "triangle index out of range"
        );
        // SAFETY: a null config string is allowed (default configuration).
        let device = unsafe { rtcNewDevice(std::ptr::null()) };
        assert!(!device.is_null(), "rtcNewDevice failed");
        // SAFETY: `device` is a live device handle.
        let scene = unsafe { rtcNewScene(device) };
        let this = EmbreeScene { device, scene };
        this.check("rtcNewScene");
        // SAFETY: `scene` is live and not yet committed; the enum values are from the headers.
        unsafe {
            rtcSetSceneFlags(scene, RTC_SCENE_FLAG_NONE);
            rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_HIGH);
        }
        // Embree rejects zero-sized buffers; an empty mesh is a scene without geometry.
        if !triangles.is_empty() {
            // SAFETY: `device` is live; the geometry type is from the headers.
            let geometry = unsafe { rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE) };
            this.check("rtcNewGeometry");
            // SAFETY: `geometry` is live. Each buffer is allocated by Embree with room for
            // `count` items of `stride` bytes (and padding beyond); the copies write exactly
            // `count * stride` bytes into it, from slices of that many bytes, after the null
            // check. `[f32; 3]` and `[u32; 3]` are 12 bytes, the FLOAT3 and UINT3 strides.
            unsafe {
                rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_HIGH);
                let vertices = rtcSetNewGeometryBuffer(
                    geometry,
                    RTC_BUFFER_TYPE_VERTEX,
                    0,
                    RTC_FORMAT_FLOAT3,
                    12,
                    positions.len(),
                );
                this.check("rtcSetNewGeometryBuffer(vertex)");
                assert!(!vertices.is_null());
                std::ptr::copy_nonoverlapping(
                    positions.as_ptr().cast::<u8>(),
                    vertices.cast::<u8>(),
                    std::mem::size_of_val(positions),
                );
                let indices = rtcSetNewGeometryBuffer(
                    geometry,
                    RTC_BUFFER_TYPE_INDEX,
                    0,
                    RTC_FORMAT_UINT3,
                    12,
                    triangles.len(),
                );
                this.check("rtcSetNewGeometryBuffer(index)");
                assert!(!indices.is_null());
                std::ptr::copy_nonoverlapping(
                    triangles.as_ptr().cast::<u8>(),
                    indices.cast::<u8>(),
                    std::mem::size_of_val(triangles),
                );
                rtcCommitGeometry(geometry);
                this.check("rtcCommitGeometry");
                rtcAttachGeometry(scene, geometry);
                this.check("rtcAttachGeometry");
                // The scene holds its own reference now.
                rtcReleaseGeometry(geometry);
            }
        }
        // SAFETY: `scene` is live; committing builds the BVH and makes the scene queryable.
        unsafe { rtcCommitScene(scene) };
        this.check("rtcCommitScene");
        this
    }

    /// Panics with Embree's message if the device has recorded an error.
    fn check(&self, what: &str) {
        // SAFETY: `device` is live. The returned strings are static or owned by the device and
        // valid until the next API call; they are copied before that.
        unsafe {
            let code = rtcGetDeviceError(self.device);
            if code != RTC_ERROR_NONE {
                let name = cstr(rtcGetErrorString(code));
                let message = cstr(rtcGetDeviceLastErrorMessage(self.device));
                panic!("Embree: {what} failed: {name}: {message}");
            }
        }
    }

    fn property(&self, prop: c_int) -> isize {
        // SAFETY: `device` is live; the property values are from the headers.
        unsafe { rtcGetDeviceProperty(self.device, prop) }
    }

    /// The library's version, e.g. `4.4.0` (`RTC_DEVICE_PROPERTY_VERSION` is
    /// `major * 10000 + minor * 100 + patch`).
    pub fn version(&self) -> String {
        let v = self.property(RTC_DEVICE_PROPERTY_VERSION);
        format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
    }

    /// One line for benchmark output: version, configuration and the library's build options
    /// that change answers or speed.
    pub fn describe(&self) -> String {
        let tasking = match self.property(RTC_DEVICE_PROPERTY_TASKING_SYSTEM) {
            0 => "internal",
            1 => "TBB",
            2 => "PPL",
            _ => "unknown",
        };
        format!(
            "Embree {} ({SCENE_FLAGS}, {BUILD_QUALITY}, backface culling {}, {tasking} tasking), rtcIntersect1/rtcOccluded1",
            self.version(),
            if self.property(RTC_DEVICE_PROPERTY_BACKFACE_CULLING_ENABLED) != 0 {
                "ON"
            } else {
                "off"
            },
        )
    }

    /// Closest hit in `[tmin, tmax]`; `prim` is the index into the `triangles` given to `build`.
    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Hit {
        let Some((embree_ray, shift)) = embree_ray(ray) else {
            return Hit::MISS;
        };
        let mut rayhit = RTCRayHit {
            ray: embree_ray,
            hit: RTCHit {
                ng_x: 0.0,
                ng_y: 0.0,
                ng_z: 0.0,
                u: 0.0,
                v: 0.0,
                prim_id: RTC_INVALID_GEOMETRY_ID,
                geom_id: RTC_INVALID_GEOMETRY_ID,
                inst_id: [RTC_INVALID_GEOMETRY_ID],
                inst_prim_id: [RTC_INVALID_GEOMETRY_ID],
            },
        };
        // SAFETY: the scene is committed and only read (see `Sync`); `rayhit` is a valid,
        // 16-byte aligned `RTCRayHit` with the layout checked above; null args means defaults.
        unsafe { rtcIntersect1(self.scene, &mut rayhit, std::ptr::null_mut()) };
        if rayhit.hit.geom_id == RTC_INVALID_GEOMETRY_ID {
            return Hit::MISS;
        }
        Hit {
            t: (rayhit.ray.tfar + shift).clamp(ray.tmin, ray.tmax),
            prim: rayhit.hit.prim_id,
        }
    }

    /// Is any triangle hit in `[tmin, tmax]`?
    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        let Some((mut embree_ray, _)) = embree_ray(ray) else {
            return false;
        };
        // SAFETY: as in `intersect`, with an `RTCRay`.
        unsafe { rtcOccluded1(self.scene, &mut embree_ray, std::ptr::null_mut()) };
        embree_ray.tfar == f32::NEG_INFINITY
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: both handles are live and owned by `self`; the scene goes first, the device
        // after (the scene also holds a reference to it).
        unsafe {
            rtcReleaseScene(self.scene);
            rtcReleaseDevice(self.device);
        }
    }
}

/// The caller's ray as Embree takes it, and what to add to Embree's `t` to get the caller's; `None`
/// for an invalid ray. See the module documentation for the segment mapping.
#[inline(always)]
fn embree_ray(ray: &Ray) -> Option<(RTCRay, f32)> {
    if !ray.is_valid() {
        return None;
    }
    let (origin, tnear, tfar, shift) = if ray.tmin >= 0.0 {
        // One ulp below `tmin` so that `tnear < t` admits `t == tmin`; never below 0.
        (ray.origin, ray.tmin.next_down().max(0.0), ray.tmax, 0.0)
    } else {
        let start = std::array::from_fn(|i| ray.origin[i] + ray.tmin * ray.dir[i]);
        (start, 0.0, ray.tmax - ray.tmin, ray.tmin)
    };
    Some((
        RTCRay {
            org_x: origin[0],
            org_y: origin[1],
            org_z: origin[2],
            tnear,
            dir_x: ray.dir[0],
            dir_y: ray.dir[1],
            dir_z: ray.dir[2],
            time: 0.0,
            tfar,
            // Every geometry's mask is hit (masking is off in the release build anyway).
            mask: c_uint::MAX,
            id: 0,
            flags: 0,
        },
        shift,
    ))
}

/// A C string from Embree, copied; `""` for null.
///
/// # Safety
/// `p` is null or points to a NUL-terminated string valid for the duration of the call.
unsafe fn cstr(p: *const c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: non-null and NUL-terminated by the caller's contract.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}
