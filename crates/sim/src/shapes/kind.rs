//! The shape kinds the generators place, with their names and descriptions for manifests.

use serde::Serialize;

/// The shapes the generators can place. Their index in a dataset's manifest `shapes` list is the
/// `shape_id` of an object.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeKind {
    /// Cube of side 1.
    Cube,
    /// Cylinder of radius 0.5 and height 1 about z: 32-sided prism.
    Cylinder,
    /// Sphere of radius 0.5 (exact).
    Sphere,
    /// Cone of base radius 0.5 and height 1 about z, apex up: 32-sided pyramid.
    Cone,
    /// Polyhedral torus, tube radius 0.15 on a circle of radius 0.35: 24 convex slabs.
    Torus,
    /// Spur-gear-like prism, 10 teeth, thickness 0.3: root prism plus one prism per tooth.
    Gear,
    /// Trefoil knot tube: 48 convex tube segments.
    TorusKnot,
    /// Level-1 Menger sponge: 20 cubes of side 1/3.
    Sponge,
    /// Mug: open cylindrical cup with a curved handle, 25 convex parts.
    Mug,
    /// Random convex polyhedron (hull of 8 to 24 random points), different for every object.
    Hull,
}

impl ShapeKind {
    /// The MOVi-A shape set (Kubric's: cube, cylinder, sphere).
    pub const MOVI_A: [ShapeKind; 3] = [ShapeKind::Cube, ShapeKind::Cylinder, ShapeKind::Sphere];
    /// The procedural stand-in for MOVi-B's eleven assets.
    pub const MOVI_B: [ShapeKind; 10] = [
        ShapeKind::Cube,
        ShapeKind::Cylinder,
        ShapeKind::Sphere,
        ShapeKind::Cone,
        ShapeKind::Torus,
        ShapeKind::Gear,
        ShapeKind::TorusKnot,
        ShapeKind::Sponge,
        ShapeKind::Mug,
        ShapeKind::Hull,
    ];

    /// Short snake_case name, as written in manifests.
    pub fn name(self) -> &'static str {
        match self {
            ShapeKind::Cube => "cube",
            ShapeKind::Cylinder => "cylinder",
            ShapeKind::Sphere => "sphere",
            ShapeKind::Cone => "cone",
            ShapeKind::Torus => "torus",
            ShapeKind::Gear => "gear",
            ShapeKind::TorusKnot => "torus_knot",
            ShapeKind::Sponge => "sponge",
            ShapeKind::Mug => "mug",
            ShapeKind::Hull => "convex_hull",
        }
    }

    /// One-line description of the unit shape and how it is built.
    pub fn description(self) -> &'static str {
        match self {
            ShapeKind::Cube => "cube of side 1 (rapier cuboid)",
            ShapeKind::Cylinder => "cylinder, radius 0.5, height 1, axis z: convex 32-sided prism",
            ShapeKind::Sphere => "sphere of radius 0.5 (rapier ball)",
            ShapeKind::Cone => {
                "cone, base radius 0.5, height 1, apex +z: convex 32-sided pyramid; centre of \
                 mass a quarter of the height above the base"
            }
            ShapeKind::Torus => {
                "torus, tube radius 0.15 on a circle of radius 0.35 (24 x 12 facets), union of 24 \
                 convex slabs"
            }
            ShapeKind::Gear => {
                "spur-gear-like prism, 10 teeth, root radius 0.4, tip radius 0.5, thickness 0.3: \
                 convex root prism plus 10 convex teeth"
            }
            ShapeKind::TorusKnot => {
                "trefoil (2,3) knot tube with 8-sided cross-section, union of 48 convex segments \
                 (hulls of consecutive cross-sections)"
            }
            ShapeKind::Sponge => "level-1 Menger sponge: 20 cubes of side 1/3",
            ShapeKind::Mug => {
                "mug: 16-sided cylindrical cup open at the top (wall 0.1, floor 0.1) and a \
                 semicircular handle; 25 convex parts; stands in for the teapot"
            }
            ShapeKind::Hull => {
                "convex hull of 8 to 24 random points (anisotropic), a different solid for every \
                 object; stands in for the irregular scanned assets"
            }
        }
    }
}
