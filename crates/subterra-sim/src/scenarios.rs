//! Seeded generators of the built-in worlds: [`highbay`], [`cable`], [`tunnel`] (in
//! `scenarios/aerial.rs`), [`mine`], [`subway`] (`scenarios/ground.rs`), the ground trade-off
//! worlds [`slopes`], [`rough`], [`ledge`] and the [`cave`] (in `scenarios/tradeoff.rs`), and
//! the flight world [`warehouse`] of shelf racks and dense thin poles
//! (`scenarios/warehouse.rs`); [`generate`] picks one by name. Their shared helpers are in
//! `scenarios/helpers.rs`, the tests in `scenarios/tests.rs`.
//!
//! In: a scenario name and a seed. Out: a [`WorldSpec`] (plain data; `World::from_spec`
//! turns it into geometry). Every random draw comes from one
//! `Xoshiro256PlusPlus::seed_from_u64(seed)` stream, so a seed gives the same spec bit for
//! bit and different seeds give different layouts. World frame ENU, metres, radians.
//!
//! Aerial scenarios (`highbay`, `cable`, `tunnel`) put region centres at flight height;
//! ground scenarios (`mine`, `subway`) put them on the ground. Tags used: "floor",
//! "ceiling", "wall", "pole", "cable", "beam", "pipe", "column", "rock", "rubble",
//! "pillar", "rail", "bench".

use crate::error::{SimError, SimResult};
use crate::spec::WorldSpec;

mod aerial;
mod ground;
mod helpers;
#[cfg(test)]
mod tests;
mod tradeoff;
mod warehouse;

pub use aerial::{
    cable, highbay, tunnel, CABLE_DISTANCE_M, CABLE_RADIUS_M, CABLE_ROBOT_HEIGHT_M, CABLE_WALL_DISTANCE_M, HIGHBAY_CEILING_M, HIGHBAY_CLEARANCE_M,
    HIGHBAY_FLIGHT_HEIGHT_M, HIGHBAY_LENGTH_M, HIGHBAY_POLES, HIGHBAY_REGIONS, HIGHBAY_REGION_RADIUS_M, HIGHBAY_ROUTES, HIGHBAY_ROUTE_SPREAD_M, HIGHBAY_WIDTH_M,
    TUNNEL_FLIGHT_HEIGHT_M, TUNNEL_LENGTH_M, TUNNEL_WAYPOINT_SPACING_M, TUNNEL_WIDTH_M,
};
pub use ground::{
    mine, subway, MINE_COMM_NODE_KEEP_OUT_M, MINE_CORRIDOR_HALF_WIDTH_M, MINE_REGION_RADIUS_M, MINE_RESOLUTION_M, MINE_SIZE_M, SUBWAY_PLATFORM_LENGTH_M,
    SUBWAY_PLATFORM_WIDTH_M, SUBWAY_TRACK_DEPTH_M,
};
pub use tradeoff::{cave, ledge, rough, slopes, CAVE_SIZE_M, GROUND_REGION_RADIUS_M, TRADEOFF_SIZE_M};
pub use warehouse::{warehouse, WAREHOUSE_FOREST_GAP_M, WAREHOUSE_LENGTH_M, WAREHOUSE_PASSAGE_M, WAREHOUSE_REGION_RADIUS_M, WAREHOUSE_WIDTH_M};

/// Names of the built-in scenarios, in the order the docs list them.
pub const SCENARIOS: [&str; 10] = ["highbay", "cable", "tunnel", "mine", "subway", "slopes", "rough", "ledge", "cave", "warehouse"];

/// The world of the built-in scenario `name` for `seed`.
///
/// # Errors
/// [`SimError::Unknown`] (naming the known scenarios) when `name` is not one of [`SCENARIOS`].
pub fn generate(name: &str, seed: u64) -> SimResult<WorldSpec> {
    match name {
        "highbay" => Ok(highbay(seed)),
        "cable" => Ok(cable(seed)),
        "tunnel" => Ok(tunnel(seed)),
        "warehouse" => Ok(warehouse(seed)),
        "mine" => Ok(mine(seed)),
        "subway" => Ok(subway(seed)),
        "slopes" => Ok(slopes(seed)),
        "rough" => Ok(rough(seed)),
        "ledge" => Ok(ledge(seed)),
        "cave" => Ok(cave(seed)),
        _ => Err(SimError::Unknown { what: "scenario".into(), name: name.into(), known: SCENARIOS.join(", ") }),
    }
}
