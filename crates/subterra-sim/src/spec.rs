//! The world description: plain data, written by hand as TOML (see `docs/world-format.md`)
//! or produced by the scenario generators. [`crate::world::World`] turns it into geometry.
//!
//! World frame ENU (z up), metres, radians. Every primitive carries a `tag` (what it is:
//! "cable", "pole", "wall", "rubble", ...) and `dark` (a surface that returns no depth).

use serde::{Deserialize, Serialize};

/// A finite cylinder between two end points (poles, pipes, rock columns).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CylinderSpec {
    /// One end centre [m].
    pub a: [f64; 3],
    /// Other end centre [m].
    pub b: [f64; 3],
    /// Radius [m].
    pub radius: f64,
    /// What it is.
    #[serde(default)]
    pub tag: String,
    /// Absorbs the sensor's light: no depth return.
    #[serde(default)]
    pub dark: bool,
}

/// A capsule: a segment swept by a sphere (cables, hoses).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CapsuleSpec {
    /// One end of the axis [m].
    pub a: [f64; 3],
    /// Other end [m].
    pub b: [f64; 3],
    /// Radius [m].
    pub radius: f64,
    /// What it is.
    #[serde(default)]
    pub tag: String,
    /// Absorbs the sensor's light.
    #[serde(default)]
    pub dark: bool,
}

/// A box rotated by `yaw` about the vertical axis through its centre.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    /// Centre [m].
    pub centre: [f64; 3],
    /// Full side lengths along its own x, y, z [m].
    pub size: [f64; 3],
    /// Rotation about z [rad].
    #[serde(default)]
    pub yaw: f64,
    /// What it is.
    #[serde(default)]
    pub tag: String,
    /// Absorbs the sensor's light.
    #[serde(default)]
    pub dark: bool,
}

/// A sphere (boulders, rubble).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereSpec {
    /// Centre [m].
    pub centre: [f64; 3],
    /// Radius [m].
    pub radius: f64,
    /// What it is.
    #[serde(default)]
    pub tag: String,
    /// Absorbs the sensor's light.
    #[serde(default)]
    pub dark: bool,
}

/// An infinite plane; the solid side is opposite the normal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// A point on the plane [m].
    pub point: [f64; 3],
    /// Outward normal (need not be unit length, must not be zero).
    pub normal: [f64; 3],
    /// What it is.
    #[serde(default)]
    pub tag: String,
    /// Absorbs the sensor's light.
    #[serde(default)]
    pub dark: bool,
}

/// Terrain as a regular grid of heights. `heights[r][c]` is the height at
/// `x = origin[0] + c·resolution`, `y = origin[1] + r·resolution`. A NaN height (or one
/// equal to `hole_value`) marks a hole (negative obstacle): the cells touching it are removed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeightFieldSpec {
    /// World x, y of `heights[0][0]` [m].
    pub origin: [f64; 2],
    /// Spacing of the samples [m].
    pub resolution: f64,
    /// Rows along y, columns along x [m]; at least 2 x 2, all rows the same length.
    pub heights: Vec<Vec<f64>>,
    /// A height value that also marks a hole (TOML has no NaN literal in every writer).
    #[serde(default)]
    pub hole_value: Option<f64>,
    /// Surfaces absorb the sensor's light.
    #[serde(default)]
    pub dark: bool,
}

/// A named region (start and goal areas): a vertical cylinder around `centre`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// Name, e.g. "A".
    pub name: String,
    /// Centre [m].
    pub centre: [f64; 3],
    /// Radius [m].
    pub radius: f64,
}

/// A mission item (a dropped comm node, another robot): no geometry of its own unless
/// `solid`; the terrain mapper's `mission` layer keeps out of `keep_out_radius`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ItemSpec {
    /// Kind, e.g. "comm_node".
    pub kind: String,
    /// Position [m].
    pub position: [f64; 3],
    /// Keep-out radius [m].
    pub keep_out_radius: f64,
    /// Whether it is also an obstacle (a sphere of 0.15 m at `position`).
    #[serde(default)]
    pub solid: bool,
}

/// A route between two regions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteSpec {
    /// Name, e.g. "A-B".
    pub name: String,
    /// Start region.
    pub from: String,
    /// Goal region.
    pub to: String,
}

/// A whole world. TOML: top-level `name`, then `[[cylinder]]`, `[[capsule]]`, `[[box]]`,
/// `[[sphere]]`, `[[plane]]`, `[heightfield]`, `[[region]]`, `[[item]]`, `[[route]]` tables.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSpec {
    /// Name of the world.
    #[serde(default)]
    pub name: String,
    /// Cylinders.
    #[serde(default, rename = "cylinder")]
    pub cylinders: Vec<CylinderSpec>,
    /// Capsules.
    #[serde(default, rename = "capsule")]
    pub capsules: Vec<CapsuleSpec>,
    /// Boxes.
    #[serde(default, rename = "box")]
    pub boxes: Vec<BoxSpec>,
    /// Spheres.
    #[serde(default, rename = "sphere")]
    pub spheres: Vec<SphereSpec>,
    /// Planes.
    #[serde(default, rename = "plane")]
    pub planes: Vec<PlaneSpec>,
    /// Terrain.
    #[serde(default)]
    pub heightfield: Option<HeightFieldSpec>,
    /// Regions.
    #[serde(default, rename = "region")]
    pub regions: Vec<RegionSpec>,
    /// Mission items.
    #[serde(default, rename = "item")]
    pub items: Vec<ItemSpec>,
    /// Routes.
    #[serde(default, rename = "route")]
    pub routes: Vec<RouteSpec>,
}
