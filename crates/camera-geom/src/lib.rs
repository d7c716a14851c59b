//! Exact pinhole camera geometry for psneus.
//!
//! # Why this crate exists
//! Camera-convention confusion is the failure users of NeuS-style trainers report most often:
//! OpenCV vs OpenGL axes, pixel centres at integers or half-integers, `world_mat` vs `c2w`,
//! the sign ambiguities of decomposing `P = K[R|t]`. This crate pins every one of them down in
//! names and types and tests each round trip.
//!
//! # Frames and maps (the paper's notation, Sec. 3.1 and supp. C.1)
//! - **world** (`point_in_world`, x): the normalised scene frame, region of interest = unit sphere.
//! - **camera** (`point_in_camera`, x̂): OpenCV axes, +x right, +y down, +z forward (looking
//!   direction). `h(x) = camera_from_world · x` is a rigid transform.
//! - **image space** (the paper's 3D image space 𝒰, `point_in_image_space`):
//!   `g(x̂) = (x̂/ẑ, ŷ/ẑ, ẑ) = (u, v, λ)`, with (u, v) *normalised* image coordinates and λ the
//!   depth along the optical axis. `f = g∘h`. The Jacobian determinant of `f⁻¹` is `λ²`
//!   (rotations have determinant 1), so a density transforms as `p_U(u) = p_X(x)·λ²`.
//! - **pixel space** (`point_in_pixel_space`): the same with (u, v) in pixels, `(u, v) = K·(x̂/ẑ, ŷ/ẑ, 1)`.
//!   The Jacobian determinant of `world_from_pixel_space` is `λ²/(fx·fy)`. The sampler grids live
//!   here, because their (u, v) bounds come from the image corners.
//!
//! # Pixel centres
//! A pixel *index* (column, row) becomes continuous pixel coordinates through
//! [`PixelCenters`]: NeuS/IDR/DTU put the centre of pixel (i, j) at (i, j)
//! ([`PixelCenters::Integer`]); NeRF/instant-ngp/OpenGL at (i + ½, j + ½)
//! ([`PixelCenters::HalfInteger`]). `K` always maps to continuous coordinates.
#![deny(missing_docs)]

mod decompose;
mod rigid;

pub use decompose::{decompose_projection, projection_from_parts};
pub use rigid::Rigid3;

use glam::{DMat3, DVec2, DVec3};
use serde::{Deserialize, Serialize};

/// Errors for camera construction and decomposition. They carry no file names: loaders wrap them.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A matrix or parameter holds NaN or an infinity.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Which quantity was not finite.
        what: &'static str,
    },
    /// The left 3×3 block of a projection matrix is (numerically) singular.
    #[error("singular projection matrix (|det M| = {det:e} relative to its scale)")]
    SingularProjection {
        /// det(M) / ‖M‖³.
        det: f64,
    },
    /// A matrix that must be a proper rotation is not one.
    #[error("not a rotation: max |RᵀR − I| = {orthogonality_error:e}, det = {det}")]
    NotARotation {
        /// max |RᵀR − I|.
        orthogonality_error: f64,
        /// det(R).
        det: f64,
    },
    /// A focal length is zero or negative.
    #[error("focal length must be positive, got fx = {fx}, fy = {fy}")]
    BadFocal {
        /// Horizontal focal length in pixels.
        fx: f64,
        /// Vertical focal length in pixels.
        fy: f64,
    },
    /// Image width or height is zero.
    #[error("image size must be non-zero, got {width}×{height}")]
    EmptyImage {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
}

/// Where the centre of pixel (i, j) lies in continuous pixel coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum PixelCenters {
    /// Centre of pixel (i, j) at (i, j): IDR, NeuS, DTU (`cameras_sphere.npz`).
    #[default]
    Integer,
    /// Centre of pixel (i, j) at (i + ½, j + ½): NeRF-synthetic, instant-ngp, OpenGL.
    HalfInteger,
}

impl PixelCenters {
    /// Offset added to an integer index to get the pixel centre: 0 or ½.
    pub fn offset(self) -> f64 {
        match self {
            PixelCenters::Integer => 0.0,
            PixelCenters::HalfInteger => 0.5,
        }
    }
}

/// Pinhole intrinsics `K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]` in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Horizontal focal length (pixels).
    pub fx: f64,
    /// Vertical focal length (pixels).
    pub fy: f64,
    /// Principal point, x (pixels, continuous coordinates).
    pub cx: f64,
    /// Principal point, y (pixels, continuous coordinates).
    pub cy: f64,
    /// Skew `K[0][1]` (pixels); zero for almost every real camera.
    pub skew: f64,
}

impl Intrinsics {
    /// `K` as a matrix (glam is column-major: `K.row(0) = (fx, skew, cx)`).
    pub fn matrix(&self) -> DMat3 {
        DMat3::from_cols(DVec3::new(self.fx, 0.0, 0.0), DVec3::new(self.skew, self.fy, 0.0), DVec3::new(self.cx, self.cy, 1.0))
    }

    /// Normalised image coordinates (x̂/ẑ, ŷ/ẑ) → pixel coordinates.
    pub fn pixel_from_normalized(&self, n: DVec2) -> DVec2 {
        DVec2::new(self.fx * n.x + self.skew * n.y + self.cx, self.fy * n.y + self.cy)
    }

    /// Pixel coordinates → normalised image coordinates (inverse of [`Self::pixel_from_normalized`]).
    pub fn normalized_from_pixel(&self, p: DVec2) -> DVec2 {
        let y = (p.y - self.cy) / self.fy;
        let x = (p.x - self.cx - self.skew * y) / self.fx;
        DVec2::new(x, y)
    }

    /// Intrinsics of the image downscaled by an integer factor `n` with area averaging
    /// (each new pixel is the mean of an n×n block; the remainder rows/columns are dropped).
    ///
    /// With integer pixel centres the new pixel j covers old centres jn … jn+n−1, so its centre
    /// sits at old coordinate jn + (n−1)/2: `c' = (c − (n−1)/2)/n`. With half-integer centres
    /// the block edges coincide, so `c' = c/n`. Focal lengths and skew scale by 1/n.
    pub fn downscaled(&self, n: u32, centers: PixelCenters) -> Intrinsics {
        let n = n as f64;
        let shift = match centers {
            PixelCenters::Integer => (n - 1.0) / 2.0,
            PixelCenters::HalfInteger => 0.0,
        };
        Intrinsics { fx: self.fx / n, fy: self.fy / n, skew: self.skew / n, cx: (self.cx - shift) / n, cy: (self.cy - shift) / n }
    }
}

/// A ray `origin + t·direction`, `direction` of unit length, `t` a Euclidean distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    /// Ray origin in world (the camera centre for camera rays).
    pub origin: DVec3,
    /// Unit direction in world.
    pub direction: DVec3,
}

impl Ray {
    /// The point at distance `t`.
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + t * self.direction
    }
}

/// Entry and exit distances of a ray through a sphere, `None` when it misses.
///
/// `t_near` may be negative when the origin is inside the sphere; callers that need a forward
/// interval clamp it (see [`PinholeCamera::near_far_in_sphere`]).
pub fn ray_sphere(ray: &Ray, center: DVec3, radius: f64) -> Option<(f64, f64)> {
    let oc = ray.origin - center;
    let b = oc.dot(ray.direction);
    // Distance² of the closest approach, computed without cancellation (|oc|² − b² loses digits
    // for far-away origins).
    let closest = oc - b * ray.direction;
    let h = radius * radius - closest.length_squared();
    if h < 0.0 {
        return None;
    }
    let h = h.sqrt();
    Some((-b - h, -b + h))
}

/// Bounds of a camera's 3D image space in pixel space: u, v in pixels, λ in world length units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImageSpaceBounds {
    /// `[u_min, u_max]` (pixels, continuous).
    pub u: [f64; 2],
    /// `[v_min, v_max]` (pixels, continuous).
    pub v: [f64; 2],
    /// `[λ_min, λ_max]`, depth along the optical axis; `λ_min > 0`.
    pub depth: [f64; 2],
}

/// Which depth range [`PinholeCamera::image_space_bounds`] uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum DepthBounds {
    /// The paper's choice (Sec. 5.1): the central ray (through the principal point) against the
    /// scene bound sphere. Shorter than [`DepthBounds::Tight`] when the sphere's centre is off the
    /// optical axis, and then it can cut off parts of the scene seen near the image border.
    /// Falls back to `Tight` when the central ray misses the sphere.
    #[default]
    CentralRay,
    /// The full depth range of the bound sphere as seen by the camera: `[c_z − r, c_z + r]` with
    /// `c_z` the depth of the sphere's centre. Contains every visible scene point; equals
    /// `CentralRay` when the sphere is centred on the optical axis.
    Tight,
}

/// A calibrated pinhole camera: intrinsics, image size, and the rigid map world → camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Intrinsics `K`.
    pub intrinsics: Intrinsics,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// `h`: world → camera (OpenCV axes).
    pub camera_from_world: Rigid3,
    /// Pixel-centre convention for pixel indices.
    pub pixel_centers: PixelCenters,
}

/// Tolerance on `max |RᵀR − I|` for accepting a rotation read from a file (files often store f32).
pub const ROTATION_TOLERANCE: f64 = 1e-4;

impl PinholeCamera {
    /// Builds a camera after checking that every value is finite, the focal lengths positive,
    /// the image non-empty and the rotation proper (within [`ROTATION_TOLERANCE`]; the rotation
    /// is then re-orthonormalised so round trips are exact to f64 precision).
    pub fn new(intrinsics: Intrinsics, width: u32, height: u32, camera_from_world: Rigid3, pixel_centers: PixelCenters) -> Result<Self, CameraError> {
        let k = intrinsics;
        if ![k.fx, k.fy, k.cx, k.cy, k.skew].iter().all(|v| v.is_finite()) {
            return Err(CameraError::NonFinite { what: "intrinsics" });
        }
        if k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(CameraError::BadFocal { fx: k.fx, fy: k.fy });
        }
        if width == 0 || height == 0 {
            return Err(CameraError::EmptyImage { width, height });
        }
        let camera_from_world = camera_from_world.validated(ROTATION_TOLERANCE)?;
        Ok(PinholeCamera { intrinsics, width, height, camera_from_world, pixel_centers })
    }

    /// `h⁻¹`: camera → world.
    pub fn world_from_camera(&self) -> Rigid3 {
        self.camera_from_world.inverse()
    }

    /// The camera centre in world.
    pub fn center_in_world(&self) -> DVec3 {
        self.world_from_camera().translation
    }

    /// The optical axis (+z of the camera) in world.
    pub fn axis_in_world(&self) -> DVec3 {
        self.camera_from_world.rotation.row(2)
    }

    /// `h`: a world point in camera coordinates.
    pub fn point_in_camera(&self, point_in_world: DVec3) -> DVec3 {
        self.camera_from_world.transform_point(point_in_world)
    }

    /// `h⁻¹`: a camera point in world coordinates.
    pub fn point_in_world(&self, point_in_camera: DVec3) -> DVec3 {
        self.camera_from_world.inverse_transform_point(point_in_camera)
    }

    /// `f = g∘h`: world → the paper's (normalised) 3D image space (u, v, λ).
    pub fn image_space_from_world(&self, point_in_world: DVec3) -> DVec3 {
        image_space_from_camera(self.point_in_camera(point_in_world))
    }

    /// `f⁻¹`: (u, v, λ) in normalised image space → world.
    pub fn world_from_image_space(&self, point_in_image_space: DVec3) -> DVec3 {
        self.point_in_world(camera_from_image_space(point_in_image_space))
    }

    /// World → pixel space (u, v in pixels, λ depth).
    pub fn pixel_space_from_world(&self, point_in_world: DVec3) -> DVec3 {
        let n = self.image_space_from_world(point_in_world);
        let p = self.intrinsics.pixel_from_normalized(n.truncate());
        p.extend(n.z)
    }

    /// Pixel space (u, v in pixels, λ depth) → world.
    pub fn world_from_pixel_space(&self, point_in_pixel_space: DVec3) -> DVec3 {
        let n = self.intrinsics.normalized_from_pixel(point_in_pixel_space.truncate());
        self.world_from_image_space(n.extend(point_in_pixel_space.z))
    }

    /// `|det ∂(world_from_pixel_space)/∂(u, v, λ)| = λ²/(fx·fy)`: multiply a world density by this
    /// to get a pixel-space density.
    pub fn jacobian_det_world_from_pixel_space(&self, depth: f64) -> f64 {
        depth * depth / (self.intrinsics.fx * self.intrinsics.fy)
    }

    /// The side of one pixel at `point_in_world`, in world units: `depth/√(fx·fy)`, the side of
    /// the square with the area of the pixel's footprint on a plane facing the camera at that
    /// depth. `None` for a point at or
    /// behind the camera centre, where no pixel sees it.
    pub fn pixel_footprint_at(&self, point_in_world: DVec3) -> Option<f64> {
        let depth = self.point_in_camera(point_in_world).z;
        (depth > 0.0).then(|| depth / (self.intrinsics.fx * self.intrinsics.fy).sqrt())
    }

    /// Continuous pixel coordinates of the centre of pixel (column, row).
    pub fn pixel_center(&self, column: u32, row: u32) -> DVec2 {
        let o = self.pixel_centers.offset();
        DVec2::new(column as f64 + o, row as f64 + o)
    }

    /// The pixel (column, row) whose centre is nearest to continuous coordinates `pixel`,
    /// `None` outside the image.
    pub fn nearest_pixel(&self, pixel: DVec2) -> Option<(u32, u32)> {
        // Nearest centre = floor(x − o + ½); truncation is floor for non-negative values and
        // avoids a libm call on this hot path of the sampler.
        let o = self.pixel_centers.offset() - 0.5;
        let (c, r) = (pixel.x - o, pixel.y - o);
        if c >= 0.0 && r >= 0.0 && c < self.width as f64 && r < self.height as f64 { Some((c as u32, r as u32)) } else { None }
    }

    /// Ray from the camera centre through continuous pixel coordinates `pixel`.
    pub fn ray_through_pixel(&self, pixel: DVec2) -> Ray {
        let n = self.intrinsics.normalized_from_pixel(pixel);
        let dir_cam = DVec3::new(n.x, n.y, 1.0).normalize();
        Ray { origin: self.center_in_world(), direction: self.camera_from_world.rotation.transpose() * dir_cam }
    }

    /// Ray through the centre of pixel (column, row), by the camera's [`PixelCenters`].
    pub fn ray_through_pixel_index(&self, column: u32, row: u32) -> Ray {
        self.ray_through_pixel(self.pixel_center(column, row))
    }

    /// Depth λ per unit of distance along `direction`: `λ = t · (direction · axis)`.
    pub fn depth_per_distance(&self, direction: DVec3) -> f64 {
        direction.dot(self.axis_in_world())
    }

    /// The forward interval `[near, far]` of a camera ray inside a sphere (NeuS's near/far),
    /// `near ≥ min_distance` so that a camera inside the sphere still gets a positive start.
    pub fn near_far_in_sphere(&self, ray: &Ray, center: DVec3, radius: f64, min_distance: f64) -> Option<(f64, f64)> {
        let (t0, t1) = ray_sphere(ray, center, radius)?;
        if t1 <= min_distance {
            return None;
        }
        Some((t0.max(min_distance), t1))
    }

    /// The bounds of this camera's 3D image space (pixel space) for a bound sphere.
    ///
    /// u, v span the image from corner to corner (pixel edges, not centres). `min_depth` (> 0)
    /// is the smallest depth returned, so that a camera inside or touching the sphere still gets
    /// a valid, positive range.
    pub fn image_space_bounds(&self, center: DVec3, radius: f64, mode: DepthBounds, min_depth: f64) -> ImageSpaceBounds {
        let o = self.pixel_centers.offset() - 0.5;
        let u = [o, self.width as f64 + o];
        let v = [o, self.height as f64 + o];
        let c_z = self.point_in_camera(center).z;
        let tight = [(c_z - radius).max(min_depth), (c_z + radius).max(2.0 * min_depth)];
        let depth = match mode {
            DepthBounds::Tight => tight,
            DepthBounds::CentralRay => {
                let k = self.intrinsics;
                let ray = self.ray_through_pixel(DVec2::new(k.cx, k.cy));
                match ray_sphere(&ray, center, radius) {
                    // The central ray is the optical axis: distance = depth.
                    Some((t0, t1)) if t1 > min_depth => [t0.max(min_depth), t1],
                    _ => tight,
                }
            }
        };
        ImageSpaceBounds { u, v, depth }
    }

    /// `P = K[R|t]` (3×4, row-major) of this camera.
    pub fn projection_matrix(&self) -> [[f64; 4]; 3] {
        projection_from_parts(&self.intrinsics, &self.camera_from_world)
    }

    /// The camera looking from `eye` at `target` with `up` roughly up in the image (OpenCV axes:
    /// image +y is down, so world `up` maps to −y).
    pub fn look_at(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        intrinsics: Intrinsics,
        width: u32,
        height: u32,
        pixel_centers: PixelCenters,
    ) -> Result<Self, CameraError> {
        let z = (target - eye).normalize();
        let mut x = z.cross(up);
        if x.length_squared() < 1e-18 {
            x = z.any_orthonormal_vector();
        }
        let x = x.normalize();
        let y = z.cross(x);
        // Rows of camera_from_world.rotation are the camera axes in world.
        let rotation = DMat3::from_cols(x, y, z).transpose();
        let camera_from_world = Rigid3 { rotation, translation: -(rotation * eye) };
        PinholeCamera::new(intrinsics, width, height, camera_from_world, pixel_centers)
    }
}

/// `g`: camera coordinates → normalised 3D image space (x̂/ẑ, ŷ/ẑ, ẑ). Defined for ẑ ≠ 0; the
/// sampler only uses it for ẑ > 0.
pub fn image_space_from_camera(point_in_camera: DVec3) -> DVec3 {
    let p = point_in_camera;
    DVec3::new(p.x / p.z, p.y / p.z, p.z)
}

/// `g⁻¹`: (u, v, λ) → (uλ, vλ, λ). Its Jacobian determinant is λ².
pub fn camera_from_image_space(point_in_image_space: DVec3) -> DVec3 {
    let u = point_in_image_space;
    DVec3::new(u.x * u.z, u.y * u.z, u.z)
}

/// `|det ∂f⁻¹/∂u| = λ²` (the paper's eq. for the change of variables, supp. eq. C.3).
pub fn jacobian_det_world_from_image_space(point_in_image_space: DVec3) -> f64 {
    point_in_image_space.z * point_in_image_space.z
}

#[cfg(test)]
mod tests;
