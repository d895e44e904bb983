//! The pinhole camera of renders and primary ray sets, and the bounds it frames.

use glam::DVec3;

use crate::geom::Ray;

/// An axis-aligned box, world units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub min: [f32; 3],
    pub max: [f32; 3],
}

impl Bounds {
    pub fn of_points(points: impl IntoIterator<Item = [f32; 3]>) -> Bounds {
        let mut b = Bounds {
            min: [f32::INFINITY; 3],
            max: [f32::NEG_INFINITY; 3],
        };
        for p in points {
            for (k, &c) in p.iter().enumerate() {
                b.min[k] = b.min[k].min(c);
                b.max[k] = b.max[k].max(c);
            }
        }
        b
    }

    pub fn centre(&self) -> [f64; 3] {
        std::array::from_fn(|k| (self.min[k] as f64 + self.max[k] as f64) * 0.5)
    }

    pub fn diagonal(&self) -> f64 {
        (0..3)
            .map(|k| (self.max[k] as f64 - self.min[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    }
}

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f64; 3],
    pub target: [f64; 3],
    pub up: [f64; 3],
    /// Vertical field of view, degrees.
    pub fov_y: f64,
}

impl Camera {
    /// A camera that frames `bounds`: looking at its centre from the front (+z), a little from
    /// the right and above, at 0.8 of the distance at which the bounding sphere would just fit
    /// the view (meshes rarely fill their bounding sphere).
    pub fn framing(bounds: &Bounds) -> Camera {
        let c = bounds.centre();
        let radius = (0.5 * bounds.diagonal()).max(f64::MIN_POSITIVE);
        let fov_y: f64 = 40.0;
        let dist = radius / (fov_y.to_radians() * 0.5).sin() * 0.8;
        let dir = unit(DVec3::new(0.35, 0.3, 1.0));
        Camera {
            eye: std::array::from_fn(|k| c[k] + dir[k] * dist),
            target: c,
            up: [0.0, 1.0, 0.0],
            fov_y,
        }
    }

    /// A camera at `from` looking at `at`, `up` giving the image's up direction, with a vertical
    /// field of view of `fov_deg` degrees (an NFF/AFF viewpoint). The error says which of these
    /// cannot make a camera: non-finite values, `from == at`, `up` parallel to the view
    /// direction, or a field of view outside (0, 180).
    pub fn look_at(
        from: [f64; 3],
        at: [f64; 3],
        up: [f64; 3],
        fov_deg: f64,
    ) -> Result<Camera, String> {
        if !from.iter().chain(&at).chain(&up).all(|c| c.is_finite()) {
            return Err("the camera's from, at and up must be finite".into());
        }
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(format!(
                "the field of view is {fov_deg} degrees; it must be between 0 and 180"
            ));
        }
        let f = DVec3::from(at) - DVec3::from(from);
        let fl = f.length();
        if !(fl.is_finite() && fl > 0.0) {
            return Err("the camera looks from the point it looks at".into());
        }
        let up = DVec3::from(up);
        let ul = up.length();
        if !(ul.is_finite() && ul > 0.0) || f.cross(up).length() <= 1e-9 * fl * ul {
            return Err("the camera's up vector is zero or parallel to its view direction".into());
        }
        Ok(Camera {
            eye: from,
            target: at,
            up: up.into(),
            fov_y: fov_deg,
        })
    }

    /// One ray through the centre of each pixel, row by row from the top left; unit directions.
    pub fn primary_rays(&self, width: u32, height: u32) -> Vec<Ray> {
        let mut rays = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            rays.extend(self.row(width, height, y));
        }
        rays
    }

    /// The rays of pixel row `y` of a `width` x `height` image (see [`Self::primary_rays`]).
    pub fn row(&self, width: u32, height: u32, y: u32) -> impl Iterator<Item = Ray> + use<> {
        let view = self.pixels(width, height);
        (0..width).map(move |x| view.ray(x, y))
    }

    /// The rays of a `width` x `height` image, pixel by pixel in any order.
    pub fn pixels(&self, width: u32, height: u32) -> PixelRays {
        PixelRays::new(self, width, height)
    }
}

/// A camera's basis for one image size, from which each pixel's ray is made: bit for bit the
/// ray [`Camera::row`] and [`Camera::primary_rays`] give for that pixel.
#[derive(Clone, Copy, Debug)]
pub struct PixelRays {
    f: DVec3,
    r: DVec3,
    u: DVec3,
    h: f64,
    w: f64,
    eye: [f32; 3],
    width: u32,
    height: u32,
}

impl PixelRays {
    fn new(c: &Camera, width: u32, height: u32) -> PixelRays {
        let f = unit(DVec3::from(c.target) - DVec3::from(c.eye));
        let r = unit(f.cross(DVec3::from(c.up)));
        let u = r.cross(f);
        let h = (c.fov_y.to_radians() * 0.5).tan();
        let w = h * width as f64 / height as f64;
        PixelRays {
            f,
            r,
            u,
            h,
            w,
            eye: c.eye.map(|x| x as f32),
            width,
            height,
        }
    }

    /// The ray through the centre of pixel `(x, y)` (`(0, 0)` is the top left).
    #[inline]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        let sy = (1.0 - (y as f64 + 0.5) / self.height as f64 * 2.0) * self.h;
        let sx = ((x as f64 + 0.5) / self.width as f64 * 2.0 - 1.0) * self.w;
        // (Summed per axis as `f + sx r + sy u`, left to right: the bits of the ray set.)
        let d = unit(self.f + sx * self.r + sy * self.u);
        Ray::new(self.eye, d.to_array().map(|x| x as f32), 0.0, f32::INFINITY)
    }
}

/// `v / |v|` (`v` itself if it is zero). Divides, rather than multiplying by the reciprocal as
/// `DVec3::normalize` does, so that the ray sets keep their bits.
pub(crate) fn unit(v: DVec3) -> DVec3 {
    let l = v.length();
    if l > 0.0 { v / l } else { v }
}
