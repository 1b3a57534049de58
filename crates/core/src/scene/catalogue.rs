//! The scene catalogue. Names are part of the interface; each entry says what it tests.

use super::camera::{Camera, Projection};
use super::material::{Material, Pattern};
use super::math::{rotation, Rigid};
use super::shapes::Shape;
use super::{Anim, Object, SceneDef, Settings};
use crate::rng::SplitMix64;
use glam::{DMat3, DVec3};
use std::f64::consts::PI;
use std::sync::Arc;

/// One catalogue entry.
pub struct Entry {
    /// Name (`afterimage scene NAME`).
    pub name: &'static str,
    /// What it tests.
    pub description: &'static str,
    /// Builds the scene for the given settings (sizes in pixels matter to some).
    pub build: fn(&Settings) -> SceneDef,
}

/// Every scene.
pub const CATALOGUE: &[Entry] = &[
    Entry {
        name: "thin-line",
        description: "Shinya 1993, experiment 1: a bar 1/8 px wide, 1 degree off horizontal, moving 0.22 px/frame vertically, orthographic; white on black",
        build: thin_line,
    },
    Entry {
        name: "spokes",
        description: "Shinya 1993, experiment 2: 12 thin radial rectangles rotating with accelerating (non-uniform) speed, orthographic",
        build: spokes,
    },
    Entry {
        name: "flyover",
        description: "textured ground and blocks under a camera on a non-linear path: reprojection of everything, texture aliasing",
        build: flyover,
    },
    Entry {
        name: "moving-sphere",
        description: "the thesis's ghosting test: a textured, spinning sphere crossing a striped alley before a still camera (disocclusion)",
        build: moving_sphere,
    },
    Entry {
        name: "fence",
        description: "thin posts, rails and wires under a panning camera: the thesis's blinds, sub-pixel geometry in motion",
        build: fence,
    },
    Entry {
        name: "foliage",
        description: "160 thin swaying blades over a ground, slow dolly: the flicker case of PHLM's OPENWORLD",
        build: foliage,
    },
    Entry {
        name: "dynamic-light",
        description: "still camera, moving sun, specular spheres: shading changes with no motion at all (temporal lag)",
        build: dynamic_light,
    },
    Entry {
        name: "static",
        description: "nothing moves: zone plate, checker and thin poles; jittered accumulation should converge to the reference, and history must stay stable",
        build: static_scene,
    },
    Entry {
        name: "camera-cut",
        description: "two unrelated shots with a cut half way (that frame has reset set): nothing of the first may survive",
        build: camera_cut,
    },
    Entry {
        name: "hdr",
        description: "emitters of 1e4 beside surfaces of albedo 1e-3, slowly moving: extreme dynamic range and fireflies",
        build: hdr,
    },
];

fn v(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

fn fixed<T: Copy + Send + Sync + 'static>(x: T) -> Anim<T> {
    Arc::new(move |_| x)
}

fn object(name: impl Into<String>, id: u32, shape: Shape, material: Material, motion: Anim<Rigid>) -> Object {
    Object {
        name: name.into(),
        id,
        shape,
        material,
        motion,
    }
}

/// Defaults shared by the lit scenes: a warm sun, a cool ambient term, a blue sky.
fn lit(name: &'static str, camera: Anim<Camera>, objects: Vec<Object>) -> SceneDef {
    SceneDef {
        name,
        description: CATALOGUE
            .iter()
            .find(|e| e.name == name)
            .map_or("", |e| e.description),
        objects,
        camera,
        sun: fixed(v(0.45, 0.8, 0.35)),
        sun_irradiance: v(0.85, 0.8, 0.72),
        sun_angular_radius: 4.0_f64.to_radians(),
        ambient: v(0.16, 0.18, 0.22),
        sky_top: v(0.35, 0.55, 0.9),
        sky_horizon: v(0.75, 0.82, 0.9),
        cut_at: None,
        fog_distance: Some(40.0),
    }
}

/// Emissive white on black, no light: the colour is exactly the coverage.
fn unlit(name: &'static str, camera: Anim<Camera>, objects: Vec<Object>) -> SceneDef {
    SceneDef {
        sun_irradiance: DVec3::ZERO,
        ambient: DVec3::ZERO,
        sky_top: DVec3::ZERO,
        sky_horizon: DVec3::ZERO,
        fog_distance: None,
        ..lit(name, camera, objects)
    }
}

fn ground(id: u32, size: f64) -> Object {
    object(
        "ground",
        id,
        Shape::Plane,
        Material::patterned(Pattern::Checker { size }, v(0.78, 0.76, 0.7), v(0.18, 0.22, 0.26)),
        fixed(Rigid::IDENTITY),
    )
}

/// A perspective camera at `pos` looking at `target`, y up, vertical field of view in
/// degrees.
fn perspective(pos: DVec3, target: DVec3, fov_y_deg: f64) -> Camera {
    Camera::look_at(
        pos,
        target,
        DVec3::Y,
        Projection::Perspective {
            fov_y: fov_y_deg.to_radians(),
        },
    )
}

/// An orthographic camera looking down -z at the xy plane, 1 world unit = 1 pixel.
fn pixel_camera(s: &Settings) -> Anim<Camera> {
    fixed(Camera::look_at(
        v(0.0, 0.0, 10.0),
        DVec3::ZERO,
        DVec3::Y,
        Projection::Orthographic {
            height: s.height as f64,
        },
    ))
}

/// Shinya's experiment 1 (Shinya 1993, sec. 5): width 1/8 px, 1 degree from the horizon,
/// 0.22 = 11/50 px/frame vertical motion.
pub const THIN_LINE_WIDTH_PX: f64 = 1.0 / 8.0;
/// Angle of the thin line from the horizon, degrees (Shinya 1993, sec. 5).
pub const THIN_LINE_ANGLE_DEG: f64 = 1.0;
/// Vertical speed of the thin line, px/frame (Shinya 1993, sec. 5: 0.22 = 11/50).
pub const THIN_LINE_SPEED_PX: f64 = 0.22;

fn thin_line(s: &Settings) -> SceneDef {
    let len = 4.0 * s.width as f64;
    let rot = rotation(DVec3::Z, THIN_LINE_ANGLE_DEG.to_radians());
    let bar = object(
        "bar",
        1,
        Shape::Cuboid {
            half: v(len / 2.0, THIN_LINE_WIDTH_PX / 2.0, 0.5),
        },
        Material::emitter(DVec3::ONE),
        // Moves down the image (world -y) from just above the centre.
        Arc::new(move |t| Rigid::new(rot, v(0.0, 3.0 - THIN_LINE_SPEED_PX * t, 0.0))),
    );
    unlit("thin-line", pixel_camera(s), vec![bar])
}

fn spokes(s: &Settings) -> SceneDef {
    let r = 0.45 * s.width.min(s.height) as f64;
    let n = 12;
    let objects = (0..n)
        .map(|k| {
            let base = 2.0 * PI * k as f64 / n as f64;
            object(
                format!("spoke_{k:02}"),
                k + 1,
                Shape::Cuboid {
                    half: v(r * 0.45, 0.3, 0.5),
                },
                Material::emitter(DVec3::ONE),
                // Angle 0.02 t + 0.0015 t^2: accelerating rotation.
                Arc::new(move |t| {
                    let a = base + 0.02 * t + 0.0015 * t * t;
                    let rot = rotation(DVec3::Z, a);
                    Rigid::new(rot, rot * v(r * 0.55, 0.0, 0.0))
                }),
            )
        })
        .collect();
    unlit("spokes", pixel_camera(s), objects)
}

fn blocks(first_id: u32) -> Vec<Object> {
    let mut rng = SplitMix64::new(0xB10C);
    let mut out = Vec::new();
    for k in 0..14 {
        let x = rng.range(-14.0, 14.0);
        let z = rng.range(-40.0, 10.0);
        let h = rng.range(1.0, 4.0);
        let id = first_id + k;
        let (shape, mat) = if k % 3 == 0 {
            (
                Shape::Cylinder {
                    radius: rng.range(0.4, 1.0),
                    half_height: h / 2.0,
                },
                Material::patterned(
                    Pattern::Stripes { period: 0.25 },
                    v(0.85, 0.4, 0.3),
                    v(0.95, 0.9, 0.85),
                ),
            )
        } else {
            (
                Shape::Cuboid {
                    half: v(rng.range(0.5, 1.5), h / 2.0, rng.range(0.5, 1.5)),
                },
                Material::patterned(
                    Pattern::Stripes { period: 0.3 },
                    v(0.3, 0.45, 0.7),
                    v(0.9, 0.88, 0.8),
                ),
            )
        };
        let rot = DMat3::from_rotation_y(rng.range(0.0, PI));
        out.push(object(
            format!("block_{k:02}"),
            id,
            shape,
            mat,
            fixed(Rigid::new(rot, v(x, h / 2.0, z))),
        ));
    }
    out
}

fn flyover(_: &Settings) -> SceneDef {
    let mut objects = vec![ground(1, 1.5)];
    objects.extend(blocks(2));
    let camera: Anim<Camera> = Arc::new(|t| {
        let pos = v(6.0 * (0.05 * t).sin(), 5.0 + (0.08 * t).sin(), 18.0 - 0.45 * t);
        let target = v(2.0 * (0.05 * t + 0.6).sin(), 0.0, pos.z - 16.0);
        perspective(pos, target, 50.0)
    });
    lit("flyover", camera, objects)
}

fn moving_sphere(_: &Settings) -> SceneDef {
    // Side walls run along z, striped.
    let side_wall = |name: &str, id, x: f64, colour: DVec3| {
        object(
            name,
            id,
            Shape::Cuboid {
                half: v(0.25, 1.5, 12.0),
            },
            Material::patterned(Pattern::Stripes { period: 0.4 }, colour, v(0.9, 0.85, 0.7)),
            fixed(Rigid::translate(v(x, 1.5, -6.0))),
        )
    };
    let left = side_wall("wall_left", 2, -4.0, v(0.75, 0.3, 0.25));
    let right = side_wall("wall_right", 3, 4.0, v(0.3, 0.5, 0.75));
    let back = object(
        "wall_back",
        4,
        Shape::Cuboid {
            half: v(4.5, 1.5, 0.25),
        },
        Material::patterned(
            Pattern::Checker { size: 0.5 },
            v(0.8, 0.78, 0.7),
            v(0.35, 0.35, 0.4),
        ),
        fixed(Rigid::translate(v(0.0, 1.5, -14.0))),
    );
    let sphere = object(
        "sphere",
        5,
        Shape::Sphere { radius: 1.0 },
        Material::patterned(
            Pattern::Checker { size: 0.35 },
            v(0.95, 0.8, 0.2),
            v(0.15, 0.1, 0.1),
        ),
        Arc::new(|t| {
            let x = -3.0 + 0.2 * t;
            let y = 1.0 + 0.25 * (0.3 * t).sin().abs();
            Rigid::new(DMat3::from_rotation_y(0.08 * t), v(x, y, -7.0))
        }),
    );
    let camera = fixed(perspective(v(0.0, 2.2, 6.0), v(0.0, 1.0, -7.0), 55.0));
    lit(
        "moving-sphere",
        camera,
        vec![ground(1, 1.0), left, right, back, sphere],
    )
}

fn fence(_: &Settings) -> SceneDef {
    let mut objects = vec![ground(1, 1.0)];
    let wood = Material::matte(v(0.55, 0.4, 0.25));
    let mut id = 2;
    for k in 0..25 {
        let x = -6.0 + 0.5 * k as f64;
        objects.push(object(
            format!("post_{k:02}"),
            id,
            Shape::Cuboid {
                half: v(0.03, 0.6, 0.03),
            },
            wood,
            fixed(Rigid::translate(v(x, 0.6, -3.0))),
        ));
        id += 1;
    }
    for (k, y) in [0.35, 0.95].iter().enumerate() {
        objects.push(object(
            format!("rail_{k}"),
            id,
            Shape::Cuboid {
                half: v(6.5, 0.035, 0.02),
            },
            wood,
            fixed(Rigid::translate(v(0.0, *y, -2.96))),
        ));
        id += 1;
    }
    let horizontal = DMat3::from_rotation_z(PI / 2.0);
    for (k, y) in [1.3, 1.45, 1.6].iter().enumerate() {
        objects.push(object(
            format!("wire_{k}"),
            id,
            Shape::Cylinder {
                radius: 0.004,
                half_height: 8.0,
            },
            Material::matte(v(0.1, 0.1, 0.1)),
            fixed(Rigid::new(horizontal, v(0.0, *y, -3.5))),
        ));
        id += 1;
    }
    // Blinds: thin horizontal slats on a wall behind the fence.
    for k in 0..12 {
        objects.push(object(
            format!("slat_{k:02}"),
            id,
            Shape::Cuboid {
                half: v(2.0, 0.02, 0.05),
            },
            Material::matte(v(0.92, 0.9, 0.85)),
            fixed(Rigid::new(
                DMat3::from_rotation_x(0.5),
                v(2.5, 0.3 + 0.12 * k as f64, -8.0),
            )),
        ));
        id += 1;
    }
    objects.push(object(
        "wall",
        id,
        Shape::Cuboid {
            half: v(3.0, 1.2, 0.1),
        },
        Material::matte(v(0.25, 0.2, 0.18)),
        fixed(Rigid::translate(v(2.5, 1.2, -8.3))),
    ));
    let camera: Anim<Camera> = Arc::new(|t| {
        let yaw = 0.25 * (0.05 * t).sin() + 0.004 * t;
        let dir = DMat3::from_rotation_y(yaw) * v(0.0, -0.08, -1.0);
        let pos = v(0.0, 1.0, 2.0);
        perspective(pos, pos + dir, 50.0)
    });
    lit("fence", camera, objects)
}

fn foliage(_: &Settings) -> SceneDef {
    let mut objects = vec![object(
        "ground",
        1,
        Shape::Plane,
        Material::patterned(
            Pattern::Checker { size: 0.5 },
            v(0.3, 0.22, 0.12),
            v(0.22, 0.16, 0.1),
        ),
        fixed(Rigid::IDENTITY),
    )];
    let mut rng = SplitMix64::new(0xF011A6E);
    for k in 0..160u32 {
        let base = v(rng.range(-4.0, 4.0), 0.0, rng.range(-9.0, 0.5));
        let height = rng.range(0.6, 1.4);
        let phase = rng.range(0.0, 2.0 * PI);
        let speed = rng.range(0.15, 0.35);
        let lean = rng.range(-0.2, 0.2);
        let turn = rng.range(0.0, PI);
        let green = v(rng.range(0.1, 0.3), rng.range(0.45, 0.75), rng.range(0.05, 0.2));
        objects.push(object(
            format!("blade_{k:03}"),
            2 + k,
            Shape::Cuboid {
                half: v(0.02, height / 2.0, 0.004),
            },
            Material::matte(green),
            // Sways about its base: rotate the blade (centred at half height) about z.
            Arc::new(move |t| {
                let sway = lean + 0.18 * (speed * t + phase).sin();
                let r = DMat3::from_rotation_y(turn) * DMat3::from_rotation_z(sway);
                Rigid::new(r, base + r * v(0.0, height / 2.0, 0.0))
            }),
        ));
    }
    let camera: Anim<Camera> = Arc::new(|t| {
        let pos = v(0.4 * (0.03 * t).sin(), 1.1, 3.0 - 0.03 * t);
        perspective(pos, v(0.0, 0.4, -4.0), 50.0)
    });
    lit("foliage", camera, objects)
}

fn dynamic_light(_: &Settings) -> SceneDef {
    let mut objects = vec![ground(1, 1.0)];
    for (k, (x, z, r)) in [(-1.8, -1.0, 0.7), (0.0, -2.0, 1.0), (1.9, -0.8, 0.6)]
        .iter()
        .enumerate()
    {
        objects.push(object(
            format!("sphere_{k}"),
            2 + k as u32,
            Shape::Sphere { radius: *r },
            Material::matte(v(0.7, 0.25 + 0.2 * k as f64, 0.3)).with_specular(0.6, 40.0),
            fixed(Rigid::translate(v(*x, *r, *z))),
        ));
    }
    objects.push(object(
        "box",
        5,
        Shape::Cuboid {
            half: v(0.5, 0.5, 0.5),
        },
        Material::patterned(
            Pattern::Stripes { period: 0.2 },
            v(0.9, 0.9, 0.85),
            v(0.2, 0.3, 0.5),
        ),
        fixed(Rigid::new(DMat3::from_rotation_y(0.6), v(0.9, 0.5, 0.8))),
    ));
    let camera = fixed(perspective(v(0.0, 2.5, 4.5), v(0.0, 0.5, -1.0), 50.0));
    SceneDef {
        sun: Arc::new(|t| {
            let az = 0.08 * t;
            let el = 0.6 + 0.2 * (0.05 * t).sin();
            v(el.cos() * az.cos(), el.sin(), el.cos() * az.sin())
        }),
        ..lit("dynamic-light", camera, objects)
    }
}

fn static_scene(_: &Settings) -> SceneDef {
    let mut objects = vec![ground(1, 0.5)];
    objects.push(object(
        "zone_plate",
        2,
        Shape::Cuboid {
            half: v(1.2, 1.2, 0.05),
        },
        Material::patterned(
            Pattern::ZonePlate { k: 60.0 },
            v(0.95, 0.95, 0.95),
            v(0.05, 0.05, 0.05),
        ),
        fixed(Rigid::new(DMat3::from_rotation_y(0.3), v(-1.0, 1.3, -2.5))),
    ));
    objects.push(object(
        "sphere",
        3,
        Shape::Sphere { radius: 0.6 },
        Material::patterned(
            Pattern::Checker { size: 0.12 },
            v(0.9, 0.5, 0.2),
            v(0.2, 0.2, 0.6),
        ),
        fixed(Rigid::translate(v(1.4, 0.6, -1.5))),
    ));
    for k in 0..6 {
        objects.push(object(
            format!("pole_{k}"),
            4 + k,
            Shape::Cylinder {
                radius: 0.01 + 0.004 * k as f64,
                half_height: 1.0,
            },
            Material::matte(v(0.1, 0.1, 0.12)),
            fixed(Rigid::new(
                DMat3::from_rotation_z(0.05 * k as f64),
                v(0.3 + 0.35 * k as f64, 1.0, -3.0),
            )),
        ));
    }
    let camera = fixed(perspective(v(0.0, 1.5, 3.0), v(0.0, 0.8, -2.0), 50.0));
    lit("static", camera, objects)
}

fn camera_cut(s: &Settings) -> SceneDef {
    let cut = (s.frames / 2).max(1);
    let mut objects = vec![ground(1, 1.0)];
    objects.extend(blocks(2));
    objects.push(object(
        "beacon",
        100,
        Shape::Sphere { radius: 0.8 },
        Material::matte(v(0.9, 0.1, 0.1)),
        fixed(Rigid::translate(v(0.0, 0.8, 0.0))),
    ));
    let camera: Anim<Camera> = Arc::new(move |t| {
        if t < cut as f64 {
            // Shot A: looking north, slow pan.
            perspective(v(0.0, 3.0, 16.0), v(2.0 * (0.03 * t).sin(), 1.0, 0.0), 50.0)
        } else {
            // Shot B: from the far side, low and looking back south.
            perspective(v(3.0, 1.2, -30.0), v(0.05 * t, 1.0, 0.0), 50.0)
        }
    });
    SceneDef {
        cut_at: Some(cut),
        ..lit("camera-cut", camera, objects)
    }
}

fn hdr(_: &Settings) -> SceneDef {
    let dark = Material::matte(DVec3::splat(1e-3));
    let mut objects = vec![object("floor", 1, Shape::Plane, dark, fixed(Rigid::IDENTITY))];
    objects.push(object(
        "back_wall",
        2,
        Shape::Cuboid {
            half: v(6.0, 3.0, 0.1),
        },
        Material::patterned(
            Pattern::Checker { size: 0.5 },
            DVec3::splat(1e-3),
            DVec3::splat(5e-3),
        ),
        fixed(Rigid::translate(v(0.0, 3.0, -4.0))),
    ));
    for (k, (e, r)) in [(1.0e4, 0.15), (1.0e2, 0.25), (1.0e4, 0.05)].iter().enumerate() {
        let (e, r) = (*e, *r);
        let k = k as f64;
        objects.push(object(
            format!("emitter_{k}"),
            3 + k as u32,
            Shape::Sphere { radius: r },
            Material::emitter(v(e, 0.9 * e, 0.7 * e)),
            Arc::new(move |t| {
                Rigid::translate(v(
                    -1.5 + 1.5 * k + 0.5 * (0.05 * t + k).sin(),
                    1.0 + 0.4 * k,
                    -2.0,
                ))
            }),
        ));
    }
    objects.push(object(
        "panel",
        6,
        Shape::Cuboid {
            half: v(0.6, 0.02, 0.3),
        },
        Material::emitter(DVec3::splat(3.0e3)),
        fixed(Rigid::translate(v(0.0, 2.6, -1.0))),
    ));
    let camera = fixed(perspective(v(0.0, 1.4, 3.0), v(0.0, 1.2, -3.0), 55.0));
    SceneDef {
        sun_irradiance: DVec3::ZERO,
        ambient: DVec3::ONE,
        sky_top: DVec3::splat(1e-3),
        sky_horizon: DVec3::splat(1e-3),
        fog_distance: None,
        ..lit("hdr", camera, objects)
    }
}
