//! Zone records for the GPU, and one LPM step's CPU work (regions → pairs → zones → records).

use super::pairing::{pair_regions_on, pair_regions_whole, PairingStats, PixelBox};
use super::regions::{BlockOwners, Region};
pub use super::zones::region_tan_half_angle;
use super::zones::{band_zone, zone_for_pair, CameraView, Zone, ZoneGeometry, ZoneSettings};
use crate::scene::{Image, View};

/// Shape code in [`ZoneRecord::shape`].
pub const ZONE_SPHERE: u32 = 0;
pub const ZONE_BOX: u32 = 1;
/// A cone from `camera_center` through the ball (`center`, `cone_radius`), cut to the distances
/// from the apex within `front_radius` of the centre's ([`Zone::Slab`]).
pub const ZONE_SLAB: u32 = 2;
/// The bits of [`ZoneRecord::shape`] that hold the shape code.
pub const ZONE_SHAPE_MASK: u32 = 0xFF;
/// OR-ed into [`ZoneRecord::shape`]: the opacity reset ignores the zone (no Gaussian is in
/// front of it or in its ball); it still holds Gaussians inside ([`LpmConfig::reset_max_zone_radius`]).
///
/// [`LpmConfig::reset_max_zone_radius`]: crate::lpm::config::LpmConfig::reset_max_zone_radius
pub const ZONE_NO_RESET: u32 = 0x100;

/// One error zone as the membership shaders read it. 64 bytes, std430-compatible:
///
/// ```glsl
/// struct Zone {            // offset
///     vec3  center;        //  0
///     float radius;        // 12  sphere radius; for a box, its circumscribed radius
///     vec3  camera_center; // 16  centre of the view the zone was seen from (the "in front" cone apex)
///     uint  shape;         // 28  0 = sphere, 1 = axis-aligned box (centre ± half_extents),
///                          //     2 = slab (the in-front cone cut to |x − o| ∈ |c − o| ± front_radius);
///                          //     | 0x100: the reset ignores the zone (ZONE_NO_RESET)
///     vec3  color;         // 32  mean ground-truth colour of R_e, linear [0, 1]
///     float front_radius;  // 44  "in front" ends at the near side of the ball of this radius
///     vec3  half_extents;  // 48  box only (zero for spheres)
///     float cone_radius;   // 60  radius of the in-front cone's base and of the reset's ball
/// };
/// ```
/// In std430 a `vec3` is 16-byte aligned and a following scalar fills its fourth slot, so the
/// Rust and GLSL layouts agree field for field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ZoneRecord {
    pub center: [f32; 3],
    pub radius: f32,
    pub camera_center: [f32; 3],
    pub shape: u32,
    pub color: [f32; 3],
    /// "In front" of the zone ends this far before its centre (along the cone): the bounding
    /// radius, so that no Gaussian inside the zone counts as in front of it, except under the
    /// authors' rules, whose cone and depth both use the box's smallest half-extent.
    pub front_radius: f32,
    pub half_extents: [f32; 3],
    pub cone_radius: f32,
}

/// Which radius the in-front cone (and the ball whose Gaussians set the reset threshold under
/// the authors' rules) takes around the zone's centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub enum ConeRadius {
    /// The zone's bounding sphere (docs/algorithms/lpm.md step 7: the cone to the zone sphere).
    Bounding,
    /// The authors' code: the box's smallest half-extent (a sphere's own radius).
    SmallestHalfExtent,
    /// The view's cone through its error region (the circumcircle of the region's box, as the
    /// paper's zone construction uses it), capped at the bounding radius: only what is drawn over
    /// the pixels that had the error counts as in front. [`zones_for_step`] sets it from the
    /// region; [`ZoneRecord::with_cone`] alone, which has no region, gives the bounding radius.
    /// The default under our rules.
    #[default]
    Region,
}

impl ConeRadius {
    pub fn parse(s: &str) -> anyhow::Result<ConeRadius> {
        Ok(match s {
            "bounding" => ConeRadius::Bounding,
            "smallest-half-extent" => ConeRadius::SmallestHalfExtent,
            "region" => ConeRadius::Region,
            other => anyhow::bail!(
                "LPM cone {other:?} is unknown. Fix: choose bounding, smallest-half-extent or region"
            ),
        })
    }
}

impl ZoneRecord {
    /// A record whose cone radius is the bounding radius ([`ConeRadius::Bounding`]).
    pub fn new(zone: &Zone, camera_center: [f64; 3], color: [f32; 3]) -> ZoneRecord {
        Self::with_cone(zone, camera_center, color, ConeRadius::Bounding)
    }

    pub fn with_cone(
        zone: &Zone,
        camera_center: [f64; 3],
        color: [f32; 3],
        cone: ConeRadius,
    ) -> ZoneRecord {
        let f = |v: [f64; 3]| [v[0] as f32, v[1] as f32, v[2] as f32];
        let s = zone.bounding_sphere();
        if let Zone::Slab {
            apex,
            center,
            tan_half_angle,
            half_depth,
        } = *zone
        {
            // A slab's cone is its own (the region's), whatever `cone` says, and so is its apex
            // (`camera_center` is not read): in front of it is the same cone nearer than the band.
            let d = glam::DVec3::from(center).distance(glam::DVec3::from(apex));
            return ZoneRecord {
                center: f(center),
                radius: s.radius as f32,
                camera_center: f(apex),
                shape: ZONE_SLAB,
                color,
                front_radius: half_depth as f32,
                half_extents: [0.0; 3],
                cone_radius: (d * tan_half_angle) as f32,
            };
        }
        let (shape, half) = match *zone {
            // (A slab returned above.)
            Zone::Sphere(_) | Zone::Slab { .. } => (ZONE_SPHERE, [0.0; 3]),
            Zone::Box { min, max } => (
                ZONE_BOX,
                [
                    0.5 * (max[0] - min[0]),
                    0.5 * (max[1] - min[1]),
                    0.5 * (max[2] - min[2]),
                ],
            ),
        };
        let cone_radius = match (cone, *zone) {
            (ConeRadius::SmallestHalfExtent, Zone::Box { .. }) => half[0].min(half[1]).min(half[2]),
            _ => s.radius,
        };
        let front_radius = match cone {
            ConeRadius::SmallestHalfExtent => cone_radius,
            ConeRadius::Bounding | ConeRadius::Region => s.radius,
        };
        ZoneRecord {
            center: f(s.center),
            radius: s.radius as f32,
            camera_center: f(camera_center),
            shape,
            color,
            front_radius: front_radius as f32,
            half_extents: f(half),
            cone_radius: cone_radius as f32,
        }
    }

    /// Narrows the in-front cone to half-angle atan(`tan_half_angle`) around the apex-to-centre
    /// axis (the ball's radius becomes |c − o|·tan), never wider than it was; where "in front"
    /// ends does not move. ([`ConeRadius::Region`].)
    pub fn narrow_cone(mut self, tan_half_angle: f64) -> ZoneRecord {
        let a = [0, 1, 2].map(|k| (self.center[k] - self.camera_center[k]) as f64);
        let h = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let r = (h * tan_half_angle.max(0.0)) as f32;
        if r < self.cone_radius {
            self.cone_radius = r;
        }
        self
    }
}

/// The colour of a point added at a zone's centre (docs/algorithms/lpm.md): the ground truth at the centre of
/// the region's box in the current view, i.e. the pixel containing that point, clamped into the
/// image. An image with alpha is composited on `background` (the one the step's render used),
/// because that is the colour the training loss compares against: a transparent pixel of a
/// NeRF-synthetic image stores black, but its target is the background. Black for an empty
/// image.
pub fn center_color(img: &Image, b: &PixelBox, background: [f32; 3]) -> [f32; 3] {
    if img.width == 0 || img.height == 0 || img.rgb.len() < 3 * (img.width * img.height) as usize {
        return [0.0; 3];
    }
    let [cx, cy] = b.center();
    let x = (cx.floor().max(0.0) as u32).min(img.width - 1);
    let y = (cy.floor().max(0.0) as u32).min(img.height - 1);
    let i = 3 * (y * img.width + x) as usize;
    let a = img.alpha_at(x, y);
    [0, 1, 2].map(|c| img.rgb[i + c] * a + background[c] * (1.0 - a))
}

/// Mean colour of the pixels whose centres lie in `b` (the nearest pixel to its centre when none
/// does). Black for an empty image. (A smoother alternative to [`center_color`]; not used by
/// the trainer, which follows docs/algorithms/lpm.md.)
pub fn mean_color(img: &Image, b: &PixelBox) -> [f32; 3] {
    if img.width == 0 || img.height == 0 || img.rgb.len() < 3 * (img.width * img.height) as usize {
        return [0.0; 3];
    }
    let clampi = |v: f64, hi: u32| (v.max(0.0) as u32).min(hi);
    // Pixel i has its centre at i + 0.5: inside when x0 ≤ i + 0.5 ≤ x1.
    let x0 = clampi((b.x0 - 0.5).ceil(), img.width);
    let x1 = clampi((b.x1 - 0.5).floor() + 1.0, img.width);
    let y0 = clampi((b.y0 - 0.5).ceil(), img.height);
    let y1 = clampi((b.y1 - 0.5).floor() + 1.0, img.height);
    let mut sum = [0.0f64; 3];
    let mut n = 0usize;
    for y in y0..y1 {
        for x in x0..x1 {
            let i = 3 * (y * img.width + x) as usize;
            for (c, s) in sum.iter_mut().enumerate() {
                *s += img.rgb[i + c] as f64;
            }
            n += 1;
        }
    }
    if n == 0 {
        let [cx, cy] = b.center();
        let x = clampi(cx.floor(), img.width - 1);
        let y = clampi(cy.floor(), img.height - 1);
        let i = 3 * (y * img.width + x) as usize;
        return [img.rgb[i], img.rgb[i + 1], img.rgb[i + 2]];
    }
    [
        (sum[0] / n as f64) as f32,
        (sum[1] / n as f64) as f32,
        (sum[2] / n as f64) as f32,
    ]
}

/// What one LPM step found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepZones {
    pub records: Vec<ZoneRecord>,
    pub zones: Vec<Zone>,
    /// The region pair each zone came from (same order as `zones`).
    pub pairs: Vec<super::pairing::RegionPair>,
    pub pairing: PairingStats,
    /// Paired regions for which no intersection point survived.
    pub no_zone: usize,
}

/// Steps 5–6 and the records for one (V, V') pair. `xy_view[i]` in `view` matches `xy_ref[i]` in
/// `reference`; `owners`, when given, restricts each region to the matches on its own error
/// blocks ([`super::pairing::RegionKeypoints::ErrorBlocks`]); `gt` is V's ground truth and `background` the
/// render's (for the zone colour).
#[allow(clippy::too_many_arguments)] // the step's inputs, each used once; a struct would only rename them
pub fn zones_for_step(
    view: &View,
    reference: &View,
    regions: &[Region],
    owners: Option<&BlockOwners>,
    xy_view: &[[f32; 2]],
    xy_ref: &[[f32; 2]],
    gt: &Image,
    background: [f32; 3],
    s: &ZoneSettings,
    cone: ConeRadius,
) -> StepZones {
    let (pairs, pairing) = match s.geometry {
        ZoneGeometry::Local => pair_regions_whole(regions, owners, xy_view, xy_ref),
        _ => pair_regions_on(regions, owners, xy_view, xy_ref),
    };
    let v = CameraView {
        camera: &view.camera,
        pose: &view.pose,
    };
    let r = CameraView {
        camera: &reference.camera,
        pose: &reference.pose,
    };
    let mut out = StepZones {
        pairing,
        ..Default::default()
    };
    let apex = view.pose.center();
    for p in &pairs {
        match zone_for_pair(v, r, p, xy_view, xy_ref, s).zone {
            Some(z) => {
                let mut record =
                    ZoneRecord::with_cone(&z, apex, center_color(gt, &p.in_view, background), cone);
                if cone == ConeRadius::Region && !matches!(z, Zone::Slab { .. }) {
                    record = record.narrow_cone(region_tan_half_angle(&view.camera, &p.in_view));
                }
                out.records.push(record);
                out.zones.push(z);
                out.pairs.push(p.clone());
            }
            None => out.no_zone += 1,
        }
    }
    out
}

/// The zones of one step from the SfM points `view` observes ([`ZoneGeometry::Local`] with
/// tracks): `xy[i]` is the pixel of the keypoint of point `world[i]`. Every region holding one
/// of them gets the band of its points' depths ([`band_zone`]) in the cone through the region's
/// own box; no neighbour view is needed. `owners`, when given, keeps to each region's own
/// blocks. The pairs record the region's box on both sides.
#[allow(clippy::too_many_arguments)] // as zones_for_step, the step's inputs, each used once
pub fn local_zones_for_step(
    view: &View,
    regions: &[Region],
    owners: Option<&BlockOwners>,
    xy: &[[f32; 2]],
    world: &[[f64; 3]],
    gt: &Image,
    background: [f32; 3],
    s: &ZoneSettings,
) -> StepZones {
    let v = CameraView {
        camera: &view.camera,
        pose: &view.pose,
    };
    let mut out = StepZones {
        pairing: PairingStats {
            regions: regions.len(),
            ..Default::default()
        },
        ..Default::default()
    };
    for (k, r) in regions.iter().enumerate() {
        let inside: Vec<u32> = (0..xy.len().min(world.len()))
            .filter(|&i| {
                let (x, y) = (xy[i][0] as f64, xy[i][1] as f64);
                r.contains(x, y) && owners.is_none_or(|o| o.owner(x, y) == Some(k))
            })
            .map(|i| i as u32)
            .collect();
        if inside.is_empty() {
            out.pairing.no_matches += 1;
            continue;
        }
        out.pairing.paired += 1;
        let own = PixelBox::from(*r);
        let points: Vec<glam::DVec3> = inside
            .iter()
            .map(|&i| glam::DVec3::from(world[i as usize]))
            .collect();
        match band_zone(v, &own, &points, 0, s).zone {
            Some(z) => {
                let record = ZoneRecord::with_cone(
                    &z,
                    view.pose.center(),
                    center_color(gt, &own, background),
                    ConeRadius::Region,
                );
                out.records.push(record);
                out.zones.push(z);
                out.pairs.push(super::pairing::RegionPair {
                    region: *r,
                    in_view: own,
                    in_reference: own,
                    matches: inside.len(),
                    matched: inside,
                });
            }
            None => out.no_zone += 1,
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn center_color_reads_the_pixel_containing_the_box_centre_clamped_into_the_image() {
        let (w, h) = (5u32, 3u32);
        let rgb: Vec<f32> = (0..w * h)
            .flat_map(|i| [i as f32, 100.0 + i as f32, 200.0 + i as f32])
            .collect();
        let img = Image {
            width: w,
            height: h,
            rgb,
            alpha: None,
        };
        let at = |x0: f64, y0: f64, x1: f64, y1: f64| {
            center_color(&img, &PixelBox { x0, y0, x1, y1 }, [0.5; 3])[0]
        };
        // Centre (2.5, 1.5): pixel (2, 1) = index 7.
        assert_eq!(at(1.0, 1.0, 4.0, 2.0), 7.0);
        // Centre exactly on a pixel boundary belongs to the pixel to its right / below.
        assert_eq!(at(0.0, 0.0, 2.0, 2.0), 6.0);
        // Outside the image: clamped to the nearest edge pixel.
        assert_eq!(at(-10.0, -10.0, -8.0, -8.0), 0.0);
        assert_eq!(at(50.0, 50.0, 52.0, 52.0), 14.0);
        let empty = Image {
            width: 0,
            height: 0,
            rgb: Vec::new(),
            alpha: None,
        };
        let b = PixelBox {
            x0: 0.0,
            y0: 0.0,
            x1: 1.0,
            y1: 1.0,
        };
        assert_eq!(center_color(&empty, &b, [1.0; 3]), [0.0; 3]);
    }

    #[test]
    fn center_color_composites_an_alpha_image_on_the_background() {
        // Pixel 0 transparent black (as NeRF-synthetic stores it), pixel 1 a quarter opaque red.
        let img = Image {
            width: 2,
            height: 1,
            rgb: vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            alpha: Some(vec![0.0, 0.25]),
        };
        let b = |x0: f64| PixelBox {
            x0,
            y0: 0.0,
            x1: x0 + 1.0,
            y1: 1.0,
        };
        assert_eq!(center_color(&img, &b(0.0), [1.0; 3]), [1.0; 3]);
        assert_eq!(
            center_color(&img, &b(1.0), [0.2, 0.4, 0.8]),
            [0.25 + 0.75 * 0.2, 0.75 * 0.4, 0.75 * 0.8]
        );
    }
}
