//! A procedural district: streets, lots and box buildings covered in flat Gaussians, and an
//! oblique aerial survey over it. The scene exists so that training past one machine can be
//! shown on a scene whose truth is known exactly (its Gaussians) and whose size is a flag: no
//! capture on disk is larger than one device here.
//!
//! Lengths are in lots (a lot is 1 × 1, a street 0.4 wide); the ground is the plane z = 0, z up.
//! Every surface is sampled on a jittered grid whose spacing is chosen so that the whole district
//! holds the asked number of Gaussians; each Gaussian is a disc in its surface (σ 0.6 of the
//! spacing, 0.05 of it across), so neighbours overlap and the surfaces render closed.

use crate::scene::camera::unit_quaternion_of_rotation;
use crate::scene::{PinholeCamera, Pose};
use crate::splats::{model::rgb_to_sh_dc, GaussianParams};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct CitySpec {
    /// Lots along x and y.
    pub lots: (usize, usize),
    /// Gaussians of the truth (the count lands within a percent or two of it).
    pub gaussians: usize,
    /// Survey views (every 8th by name is a test view when the scene is read).
    pub views: usize,
    /// Image size of every view.
    pub width: u32,
    pub height: u32,
    pub seed: u64,
}

/// Street width between lots, in lots.
pub const STREET: f64 = 0.4;
/// Survey altitude above the tallest roof's range, in lots.
pub const ALTITUDE: f64 = 2.2;
/// The survey's pitch below the horizon, degrees.
pub const PITCH_DEG: f64 = 55.0;
/// Horizontal field of view, degrees.
pub const FOV_X_DEG: f64 = 70.0;

/// A box building on a lot: ground rectangle and height, and its facade's look.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Building {
    pub min: [f64; 2],
    pub max: [f64; 2],
    pub height: f64,
    pub wall: [f32; 3],
    pub window: [f32; 3],
    pub roof: [f32; 3],
}

/// The district: its buildings, its truth and its survey.
pub struct City {
    pub buildings: Vec<Building>,
    /// The ground's rectangle (the lots plus a border the survey's views reach).
    pub ground_min: [f64; 2],
    pub ground_max: [f64; 2],
    /// The truth: every Gaussian of every surface (SH degree 0, opaque discs).
    pub params: GaussianParams,
    /// The survey: one pinhole camera and pose a view, in flight order.
    pub views: Vec<(PinholeCamera, Pose)>,
}

impl CitySpec {
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.lots.0 >= 1 && self.lots.1 >= 1 && self.lots.0 * self.lots.1 <= 10_000,
            "--lots {}x{}: give 1x1 to 100x100 lots",
            self.lots.0,
            self.lots.1
        );
        anyhow::ensure!(
            self.gaussians >= 1000,
            "--gaussians {}: a district needs at least 1000 Gaussians to cover its surfaces",
            self.gaussians
        );
        anyhow::ensure!(
            self.views >= 8,
            "--views {}: give at least 8 (every 8th is a test view)",
            self.views
        );
        anyhow::ensure!(
            self.width >= 16 && self.height >= 16,
            "--size {}x{}: give at least 16x16 pixels",
            self.width,
            self.height
        );
        Ok(())
    }
}

/// Origin of lot (i, j) on the ground.
fn lot_origin(i: usize, j: usize) -> [f64; 2] {
    [i as f64 * (1.0 + STREET), j as f64 * (1.0 + STREET)]
}

/// The district's buildings: each lot holds one building or a 2×2 of smaller ones, taller
/// towards the centre (a downtown), inset from the street by a pavement.
fn buildings(spec: &CitySpec, rng: &mut Pcg64) -> Vec<Building> {
    const WALLS: [[f32; 3]; 6] = [
        [0.62, 0.32, 0.26], // brick
        [0.82, 0.76, 0.62], // sandstone
        [0.55, 0.56, 0.58], // concrete
        [0.30, 0.42, 0.55], // glass
        [0.86, 0.86, 0.82], // plaster
        [0.45, 0.36, 0.30], // dark brick
    ];
    let (nx, ny) = spec.lots;
    let centre = [(nx as f64 - 1.0) / 2.0, (ny as f64 - 1.0) / 2.0];
    let reach = (centre[0].max(centre[1])).max(1.0);
    let mut out = Vec::new();
    for i in 0..nx {
        for j in 0..ny {
            let o = lot_origin(i, j);
            let d = ((i as f64 - centre[0]).hypot(j as f64 - centre[1]) / reach).min(1.0);
            let tall = 0.35 + 1.1 * (1.0 - d);
            let parts: Vec<([f64; 2], [f64; 2])> = if rng.gen_bool(0.4) {
                vec![([0.1, 0.1], [0.9, 0.9])]
            } else {
                let mut v = Vec::new();
                for (a, b) in [(0.08, 0.46), (0.54, 0.92)] {
                    for (c, e) in [(0.08, 0.46), (0.54, 0.92)] {
                        v.push(([a, c], [b, e]));
                    }
                }
                v
            };
            for (lo, hi) in parts {
                let wall = WALLS[rng.gen_range(0..WALLS.len())];
                let shade = rng.gen_range(0.85..1.1f32);
                out.push(Building {
                    min: [o[0] + lo[0], o[1] + lo[1]],
                    max: [o[0] + hi[0], o[1] + hi[1]],
                    height: tall * rng.gen_range(0.4..1.0),
                    wall: wall.map(|c| (c * shade).min(1.0)),
                    window: [0.12, 0.16, 0.22].map(|c| c + rng.gen_range(0.0..0.08)),
                    roof: [0.35, 0.34, 0.33].map(|c| c + rng.gen_range(-0.08..0.12)),
                });
            }
        }
    }
    out
}

/// The ground's colour at (x, y): asphalt with dashed centre lines on the streets, pavement
/// and grass inside the lots.
fn ground_colour(x: f64, y: f64, spec: &CitySpec) -> [f32; 3] {
    let period = 1.0 + STREET;
    let in_lot = |v: f64, n: usize| {
        let k = (v / period).floor();
        let f = v - k * period;
        k >= 0.0 && (k as usize) < n && f < 1.0
    };
    let (lx, ly) = (in_lot(x, spec.lots.0), in_lot(y, spec.lots.1));
    if lx && ly {
        let f = [x.rem_euclid(period), y.rem_euclid(period)];
        let edge = f[0].min(f[1]).min(1.0 - f[0]).min(1.0 - f[1]);
        return if edge < 0.07 {
            [0.72, 0.71, 0.68] // pavement
        } else {
            [0.28, 0.45, 0.22] // grass between and around the buildings
        };
    }
    // On a street: its centre line dashed (0.1 on, 0.1 off).
    let centre = |v: f64| (v.rem_euclid(period) - (1.0 + STREET / 2.0)).abs() < 0.012;
    let dash = |v: f64| v.rem_euclid(0.2) < 0.1;
    if (!lx && centre(x) && dash(y)) || (!ly && centre(y) && dash(x)) {
        return [0.9, 0.82, 0.3];
    }
    [0.24, 0.24, 0.26]
}

/// A facade's colour at height z and position u along it: windows a floor apart.
fn facade_colour(b: &Building, u: f64, z: f64) -> [f32; 3] {
    let floor = 0.12;
    let (fz, fu) = (z.rem_euclid(floor) / floor, u.rem_euclid(0.1) / 0.1);
    if z > 0.04 && z < b.height - 0.03 && (0.3..0.8).contains(&fz) && (0.25..0.75).contains(&fu) {
        b.window
    } else {
        b.wall
    }
}

/// One sampled surface: a rectangle spanned by `u` and `v` (unit, perpendicular) from
/// `origin`, of size `lu` × `lv`, and its colour at (u, v).
struct Surface<'a> {
    origin: [f64; 3],
    u: [f64; 3],
    v: [f64; 3],
    lu: f64,
    lv: f64,
    /// Sampling spacing relative to the district's (the countryside is sampled coarser).
    coarse: f64,
    colour: Box<dyn Fn(f64, f64) -> [f32; 3] + 'a>,
}

/// The countryside beyond the streets around the lots: fields a third of a lot across, each
/// its own crop's colour, so the border the survey sees has texture to fit.
fn field_colour(x: f64, y: f64, seed: u64) -> [f32; 3] {
    const CROPS: [[f32; 3]; 5] = [
        [0.36, 0.48, 0.20],
        [0.62, 0.56, 0.30],
        [0.44, 0.36, 0.24],
        [0.26, 0.38, 0.18],
        [0.70, 0.66, 0.44],
    ];
    let (i, j) = ((x / 0.33).floor() as i64, (y / 0.33).floor() as i64);
    let mut h = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ seed;
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 32;
    CROPS[(h % CROPS.len() as u64) as usize]
}

type Colour<'a> = Box<dyn Fn(f64, f64) -> [f32; 3] + 'a>;

/// A rectangle of the ground.
fn flat<'a>(lo: [f64; 2], hi: [f64; 2], coarse: f64, colour: Colour<'a>) -> Surface<'a> {
    Surface {
        origin: [lo[0], lo[1], 0.0],
        u: [1.0, 0.0, 0.0],
        v: [0.0, 1.0, 0.0],
        lu: hi[0] - lo[0],
        lv: hi[1] - lo[1],
        coarse,
        colour,
    }
}

/// Every surface: the streets and lots (the town), four strips of countryside around them to
/// the ground's edge (sampled at twice the spacing), and each building's roof and facades.
fn surfaces<'a>(
    city: &'a [Building],
    spec: &'a CitySpec,
    town: ([f64; 2], [f64; 2]),
    ground: ([f64; 2], [f64; 2]),
) -> Vec<Surface<'a>> {
    let ((tl, th), (gl, gh)) = (town, ground);
    let seed = spec.seed;
    let field = move |lo: [f64; 2]| -> Colour<'a> {
        Box::new(move |u, v| field_colour(lo[0] + u, lo[1] + v, seed))
    };
    let mut s = vec![
        flat(
            tl,
            th,
            1.0,
            Box::new(move |u, v| ground_colour(tl[0] + u, tl[1] + v, spec)),
        ),
        flat(gl, [gh[0], tl[1]], 2.0, field(gl)),
        flat([gl[0], th[1]], gh, 2.0, field([gl[0], th[1]])),
        flat([gl[0], tl[1]], [tl[0], th[1]], 2.0, field([gl[0], tl[1]])),
        flat([th[0], tl[1]], [gh[0], th[1]], 2.0, field([th[0], tl[1]])),
    ];
    for b in city {
        let (w, d, h) = (b.max[0] - b.min[0], b.max[1] - b.min[1], b.height);
        s.push(Surface {
            origin: [b.min[0], b.min[1], h],
            u: [1.0, 0.0, 0.0],
            v: [0.0, 1.0, 0.0],
            lu: w,
            lv: d,
            coarse: 1.0,
            colour: Box::new(move |_, _| b.roof),
        });
        // Four facades, each spanned by its horizontal direction and up.
        for (origin, dir, len) in [
            ([b.min[0], b.min[1]], [1.0, 0.0], w),
            ([b.min[0], b.max[1]], [1.0, 0.0], w),
            ([b.min[0], b.min[1]], [0.0, 1.0], d),
            ([b.max[0], b.min[1]], [0.0, 1.0], d),
        ] {
            s.push(Surface {
                origin: [origin[0], origin[1], 0.0],
                u: [dir[0], dir[1], 0.0],
                v: [0.0, 0.0, 1.0],
                lu: len,
                lv: h,
                coarse: 1.0,
                colour: Box::new(move |u, z| facade_colour(b, u, z)),
            });
        }
    }
    s
}

/// The survey: a grid of stations over the lots at one altitude, each looking down at
/// [`PITCH_DEG`] towards one of the four compass directions in turn, so every part of the
/// district is seen from several sides (as an oblique aerial capture).
fn survey(
    spec: &CitySpec,
    lots_min: [f64; 2],
    lots_max: [f64; 2],
    top: f64,
) -> Vec<(PinholeCamera, Pose)> {
    let size = [lots_max[0] - lots_min[0], lots_max[1] - lots_min[1]];
    // Stations on a grid with the district's aspect, four headings a station.
    let stations = spec.views.div_ceil(4).max(1);
    let nx = ((stations as f64 * size[0] / size[1]).sqrt().round() as usize).clamp(1, stations);
    let ny = stations.div_ceil(nx);
    let pitch = PITCH_DEG.to_radians();
    // A view looking at heading h stands back so that its optical axis meets the ground at
    // the station: each view is centred on the part of the district it belongs to.
    let altitude = top + ALTITUDE;
    let back = altitude / pitch.tan();
    let fx = spec.width as f64 / 2.0 / (FOV_X_DEG.to_radians() / 2.0).tan();
    let camera = PinholeCamera {
        fx,
        fy: fx,
        cx: spec.width as f64 / 2.0,
        cy: spec.height as f64 / 2.0,
        width: spec.width,
        height: spec.height,
    };
    let mut views = Vec::with_capacity(spec.views);
    for k in 0..spec.views {
        let s = k / 4;
        let (si, sj) = (s % nx, (s / nx) % ny);
        let target = [
            lots_min[0] + size[0] * (si as f64 + 0.5) / nx as f64,
            lots_min[1] + size[1] * (sj as f64 + 0.5) / ny as f64,
        ];
        let heading = (k % 4) as f64 * std::f64::consts::FRAC_PI_2 + 0.3;
        let h = [heading.cos(), heading.sin()];
        let centre = [target[0] - back * h[0], target[1] - back * h[1], altitude];
        let forward = [pitch.cos() * h[0], pitch.cos() * h[1], -pitch.sin()];
        // Camera axes in the world: x right, y down, z forward (COLMAP's).
        let right = normalise(cross(forward, [0.0, 0.0, 1.0]));
        let down = cross(forward, right);
        let rotation = [right, down, forward];
        let translation =
            [0, 1, 2].map(|r| -(0..3).map(|c| rotation[r][c] * centre[c]).sum::<f64>());
        // Through a quaternion and back, as a COLMAP file stores it: the pose read back is
        // this one to the last bit of the file's precision.
        let q = unit_quaternion_of_rotation(rotation);
        views.push((camera, Pose::from_qvec_tvec(q, translation)));
    }
    views
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalise(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|v| v / n)
}

/// The district for `spec`: deterministic in its seed.
pub fn generate(spec: &CitySpec) -> anyhow::Result<City> {
    spec.validate()?;
    let mut rng = Pcg64::seed_from_u64(spec.seed);
    let city = buildings(spec, &mut rng);
    let top = city.iter().map(|b| b.height).fold(0.0, f64::max);
    let lots_min = lot_origin(0, 0);
    let far = lot_origin(spec.lots.0 - 1, spec.lots.1 - 1);
    let lots_max = [far[0] + 1.0, far[1] + 1.0];
    // The ground reaches as far past the lots as the survey's upper image edge sees.
    let pitch = PITCH_DEG.to_radians();
    let half_fov_y =
        ((spec.height as f64 / spec.width as f64) * (FOV_X_DEG.to_radians() / 2.0).tan()).atan();
    let altitude = top + ALTITUDE;
    let border =
        (altitude / (pitch - half_fov_y).tan() - altitude / pitch.tan()).max(STREET) + STREET;
    let ground_min = [lots_min[0] - border, lots_min[1] - border];
    let ground_max = [lots_max[0] + border, lots_max[1] + border];
    // The town: the lots and the streets around them.
    let town = (
        [lots_min[0] - STREET, lots_min[1] - STREET],
        [lots_max[0] + STREET, lots_max[1] + STREET],
    );
    let surf = surfaces(&city, spec, town, (ground_min, ground_max));
    // At spacing 1 a surface holds lu·lv / coarse² Gaussians: the spacing that gives the count.
    let area: f64 = surf
        .iter()
        .map(|s| s.lu * s.lv / (s.coarse * s.coarse))
        .sum();
    let spacing = (area / spec.gaussians as f64).sqrt();
    let mut params = GaussianParams::empty(0);
    let opacity = (0.95f32 / 0.05).ln();
    for s in &surf {
        let step = spacing * s.coarse;
        let (sigma, thin) = ((0.6 * step) as f32, (0.05 * step) as f32);
        let (nu, nv) = (
            (s.lu / step).round().max(1.0) as usize,
            (s.lv / step).round().max(1.0) as usize,
        );
        let normal = cross(s.u, s.v);
        // Scales along the world axes: the surfaces are axis-aligned, so the rotation is the
        // identity and the thin axis is the normal's.
        let scale = [0, 1, 2].map(|k| if normal[k].abs() > 0.5 { thin } else { sigma }.ln());
        for a in 0..nu {
            for b in 0..nv {
                let u = (a as f64 + 0.5 + rng.gen_range(-0.3..0.3)) * s.lu / nu as f64;
                let v = (b as f64 + 0.5 + rng.gen_range(-0.3..0.3)) * s.lv / nv as f64;
                let p = [0, 1, 2].map(|k| s.origin[k] + u * s.u[k] + v * s.v[k]);
                let c = (s.colour)(u, v);
                let n = rng.gen_range(-0.03..0.03f32);
                params.positions.push(p.map(|x| x as f32));
                params.log_scales.push(scale);
                params.rotations.push([1.0, 0.0, 0.0, 0.0]);
                params.opacity_logits.push(opacity);
                params
                    .sh_dc
                    .push(c.map(|x| rgb_to_sh_dc((x + n).clamp(0.0, 1.0))));
            }
        }
    }
    drop(surf);
    let views = survey(spec, lots_min, lots_max, top);
    Ok(City {
        buildings: city,
        ground_min,
        ground_max,
        params,
        views,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> CitySpec {
        CitySpec {
            lots: (3, 2),
            gaussians: 20_000,
            views: 24,
            width: 64,
            height: 48,
            seed: 3,
        }
    }

    #[test]
    fn the_count_is_the_asked_one_and_the_city_is_its_seeds() {
        let a = generate(&spec()).unwrap();
        let n = a.params.len() as f64;
        assert!((n / 20_000.0 - 1.0).abs() < 0.05, "{n}");
        assert_eq!(a.views.len(), 24);
        let b = generate(&spec()).unwrap();
        assert_eq!(a.params, b.params);
        let c = generate(&CitySpec { seed: 4, ..spec() }).unwrap();
        assert_ne!(a.params.positions, c.params.positions);
    }

    #[test]
    fn every_view_looks_down_at_the_lots_from_above_the_roofs() {
        let s = spec();
        let city = generate(&s).unwrap();
        let top = city.buildings.iter().map(|b| b.height).fold(0.0, f64::max);
        let far = lot_origin(s.lots.0 - 1, s.lots.1 - 1);
        for (cam, pose) in &city.views {
            let c = pose.center();
            assert!(c[2] > top + 1.0, "{c:?}");
            // The image centre's ray meets the ground inside the lots.
            let axis = pose.optical_axis();
            assert!(axis[2] < -0.5, "{axis:?}");
            let t = -c[2] / axis[2];
            let hit = [c[0] + t * axis[0], c[1] + t * axis[1]];
            assert!(hit[0] > 0.0 && hit[0] < far[0] + 1.0, "{hit:?}");
            assert!(hit[1] > 0.0 && hit[1] < far[1] + 1.0, "{hit:?}");
            // The pose is a rotation: the camera's right lies in the ground plane.
            assert!(pose.rotation[0][2].abs() < 1e-12);
            assert_eq!((cam.width, cam.height), (64, 48));
        }
    }

    #[test]
    fn bad_specs_are_refused_by_name() {
        for (bad, says) in [
            (
                CitySpec {
                    lots: (0, 2),
                    ..spec()
                },
                "--lots",
            ),
            (
                CitySpec {
                    gaussians: 10,
                    ..spec()
                },
                "--gaussians",
            ),
            (CitySpec { views: 3, ..spec() }, "--views"),
            (CitySpec { width: 4, ..spec() }, "--size"),
        ] {
            let e = generate(&bad).err().unwrap().to_string();
            assert!(e.contains(says), "{e}");
        }
    }
}
