//! The one risk grid every planner reads: per-cell risks over a world-axis-aligned geometry.
//!
//! Documented on [`RiskGrid`].

use glam::DVec2;

use crate::error::{Error, Result};
use crate::terrain::{CellIndex, GridGeometry, Layer, RiskMap};

/// Most cells of a grid (2^24 = 4096 x 4096; the A*'s search state takes 28 bytes per cell).
pub(super) const MAX_GRID_CELLS: usize = 1 << 24;
/// Most cells along one side of a grid (2^16).
pub(super) const MAX_SIDE: usize = 1 << 16;
/// Largest cell side accepted \[m\]; beyond it the geometry is a mistake.
pub(super) const MAX_RESOLUTION_M: f64 = 1.0e4;
/// Smallest cell side accepted \[m\] (1 mm): no range sensor resolves less, and a denormal
/// side makes every distance a count of cells beyond any search or sampling budget.
pub(super) const MIN_RESOLUTION_M: f64 = 1.0e-3;

/// A risk grid: per-cell risks in `[0, 1]` (NaN: unknown) over a world-axis-aligned geometry.
///
/// The risk-aware A*, the MPC tracker and the navigator all take a [`RiskGrid`]: a borrowed
/// row-major `(ny, nx)` array of risks (row `iy` along world y, column `ix` along world x, the
/// layout of the terrain [`RiskMap`] layers), a cell side and the world position of cell
/// `(0, 0)`'s lower-left corner. It is validated once, when it is made:
///
/// - every value is a risk in `[0, 1]` or NaN (unknown); `+inf`, values above 1 and negative
///   values are errors naming the cell;
/// - the shape matches the values and stays within `MAX_GRID_CELLS` (2^24) / `MAX_SIDE` (2^16);
/// - the cell side is finite, positive and at most `MAX_RESOLUTION_M` (10 km); the origin is finite.
///
/// A grid made from a terrain map ([`RiskGrid::from_map`], [`RiskGrid::on_geometry`]) finds and
/// places cells exactly as the map does (world-aligned global cells), so a position falls in
/// the same cell for the mapper, the planner and the tracker.
///
/// **Lethal** is one definition for every output: a cell is lethal when its risk is at or
/// above the terrain map's `risk.lethal_risk` ([`crate::terrain::RiskConfig::lethal_risk`]).
/// The A* never enters one whatever its thresholds, the MPC turns them into obstacle
/// polygons, the counts and pictures call them lethal and an exported occupancy grid marks
/// them 100.
///
/// [`RiskMap`]: crate::terrain::RiskMap
#[derive(Debug, Clone, Copy)]
pub struct RiskGrid<'a> {
    pub(crate) risk: &'a [f32],
    pub(crate) nx: usize,
    pub(crate) ny: usize,
    pub(crate) resolution_m: f64,
    pub(crate) origin_m: DVec2,
    /// The terrain map's geometry when the grid lies on a map's: cells are then found and
    /// placed exactly as the map does (world-aligned global cells).
    map_geometry: Option<GridGeometry>,
}

impl<'a> RiskGrid<'a> {
    /// A grid of `nx x ny` cells of side `resolution_m`, whose cell `(0, 0)` has its lower-left
    /// corner at the world position `origin_m`. `risk` is row-major `(ny, nx)`: `risk[iy·nx + ix]`.
    /// Risks are in [0, 1]; NaN means unknown. Checks every value once (O(cells)); errors name
    /// the argument (`risk`, `resolution`, `origin`).
    pub fn new(risk: &'a [f32], nx: usize, ny: usize, resolution_m: f64, origin_m: DVec2) -> Result<Self> {
        if nx == 0 || ny == 0 {
            return Err(Error::input("risk", format!("is empty (shape ({ny}, {nx})); a grid needs at least one cell")));
        }
        let cells = nx.checked_mul(ny).filter(|&n| n <= MAX_GRID_CELLS && nx <= MAX_SIDE && ny <= MAX_SIDE).ok_or_else(|| {
            Error::input("risk", format!("has shape ({ny}, {nx}); at most {MAX_GRID_CELLS} cells and {MAX_SIDE} on a side"))
        })?;
        if risk.len() != cells {
            return Err(Error::input("risk", format!("has {} values but the shape ({ny}, {nx}) needs {cells}", risk.len())));
        }
        if !(resolution_m.is_finite() && (MIN_RESOLUTION_M..=MAX_RESOLUTION_M).contains(&resolution_m)) {
            return Err(Error::input(
                "resolution",
                format!("must be in [{MIN_RESOLUTION_M:e}, {MAX_RESOLUTION_M:e}] m, got {resolution_m}"),
            ));
        }
        // Within reach of every position a planner is given: a grid at x = 1e300 would hold
        // cells whose centres round to one another.
        crate::frames::check_position("origin", &origin_m.to_array())?;
        // Unknown cells (NaN) pass.
        if let Some(i) = risk.iter().position(|&r| !r.is_nan() && !(0.0..=1.0).contains(&r)) {
            return Err(Error::input(
                "risk",
                format!("has the value {} at row {}, column {}; risks must be in [0, 1] (NaN = unknown)", risk[i], i / nx, i % nx),
            ));
        }
        Ok(Self { risk, nx, ny, resolution_m, origin_m, map_geometry: None })
    }

    /// Values laid out on a terrain map's geometry `g` (row-major `(g.ny, g.nx)`): cells are
    /// found and placed as the map does. Validated as [`RiskGrid::new`].
    pub fn on_geometry(risk: &'a [f32], g: &GridGeometry) -> Result<Self> {
        let grid = Self::new(risk, g.nx, g.ny, g.resolution_m, g.origin_m())?;
        Ok(Self { map_geometry: Some(*g), ..grid })
    }

    /// The `risk` layer of a terrain map, with its geometry: a world position is in the cell
    /// [`GridGeometry::cell_of`] gives, and a cell's centre is [`GridGeometry::centre_of`].
    pub fn from_map(map: &'a RiskMap) -> Result<Self> {
        Self::on_geometry(map.get(Layer::Risk), map.geometry())
    }

    /// Cells along world x.
    pub fn nx(&self) -> usize {
        self.nx
    }
    /// Cells along world y.
    pub fn ny(&self) -> usize {
        self.ny
    }
    /// Cell side [m/cell].
    pub fn resolution_m(&self) -> f64 {
        self.resolution_m
    }
    /// World position of cell `(0, 0)`'s lower-left corner \[m\].
    pub fn origin_m(&self) -> DVec2 {
        self.origin_m
    }
    /// The risks, row-major `(ny, nx)`.
    pub fn risk(&self) -> &'a [f32] {
        self.risk
    }
    /// The terrain map geometry the grid lies on, if it was made on one.
    pub fn map_geometry(&self) -> Option<&GridGeometry> {
        self.map_geometry.as_ref()
    }

    /// The cell holding the world position `p` (`floor((p - origin)/res)`, or the map's rule),
    /// if inside the grid.
    pub fn cell_of(&self, p: DVec2) -> Option<CellIndex> {
        if let Some(g) = &self.map_geometry {
            return g.cell_of(p.x, p.y);
        }
        let q = ((p - self.origin_m) / self.resolution_m).floor();
        if q.x >= 0.0 && q.y >= 0.0 && q.x < self.nx as f64 && q.y < self.ny as f64 {
            Some(CellIndex { ix: q.x as u32, iy: q.y as u32 })
        } else {
            None
        }
    }

    /// World position of a cell's centre \[m\].
    pub fn centre_of(&self, cell: CellIndex) -> DVec2 {
        if let Some(g) = &self.map_geometry {
            return g.centre_of(cell);
        }
        self.origin_m + (DVec2::new(cell.ix as f64, cell.iy as f64) + 0.5) * self.resolution_m
    }

    /// The value at the world position `p` (NaN stays NaN), if on the grid.
    pub fn value_at(&self, p: DVec2) -> Option<f32> {
        self.cell_of(p).map(|c| self.risk[self.flat(c)])
    }

    /// The risk at `p`: the cell's value, or `None` outside the grid or where it is unknown.
    pub fn risk_at(&self, p: DVec2) -> Option<f64> {
        self.value_at(p).filter(|r| !r.is_nan()).map(f64::from)
    }

    /// Position of a cell in the value array: `iy·nx + ix`.
    pub fn flat(&self, cell: CellIndex) -> usize {
        cell.iy as usize * self.nx + cell.ix as usize
    }

    /// The cell at a position in the value array.
    pub fn cell_at(&self, flat: usize) -> CellIndex {
        CellIndex { ix: (flat % self.nx) as u32, iy: (flat / self.nx) as u32 }
    }

    pub(crate) fn check_cell(&self, argument: &str, cell: CellIndex) -> Result<()> {
        if (cell.ix as usize) < self.nx && (cell.iy as usize) < self.ny {
            Ok(())
        } else {
            Err(Error::input(argument, format!("cell (ix={}, iy={}) is outside the grid of {} x {} cells", cell.ix, cell.iy, self.nx, self.ny)))
        }
    }

    pub(crate) fn locate(&self, argument: &str, p: DVec2) -> Result<CellIndex> {
        crate::frames::check_position(argument, &p.to_array())?;
        self.cell_of(p).ok_or_else(|| {
            let (o, res) = (self.origin_m, self.resolution_m);
            Error::input(
                argument,
                format!(
                    "({}, {}) lies outside the grid, which covers x in [{}, {}), y in [{}, {}) m",
                    p.x,
                    p.y,
                    o.x,
                    o.x + self.nx as f64 * res,
                    o.y,
                    o.y + self.ny as f64 * res
                ),
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_outside_the_unit_interval_are_refused_naming_the_cell() {
        let ok = [0.0, 0.5, 1.0, f32::NAN];
        assert!(RiskGrid::new(&ok, 2, 2, 0.1, DVec2::ZERO).is_ok());
        for bad in [f32::INFINITY, 1.5, -0.1, f32::NEG_INFINITY] {
            let values = [0.0, 0.0, bad, 0.0];
            let e = RiskGrid::new(&values, 2, 2, 0.1, DVec2::ZERO).unwrap_err().to_string();
            assert!(e.contains("`risk`") && e.contains("row 1, column 0") && e.contains("[0, 1]"), "{e}");
        }
        assert!(RiskGrid::new(&ok, 3, 2, 0.1, DVec2::ZERO).unwrap_err().to_string().contains("`risk`"));
        assert!(RiskGrid::new(&ok, 2, 2, 0.0, DVec2::ZERO).unwrap_err().to_string().contains("`resolution`"));
        assert!(RiskGrid::new(&ok, 2, 2, 0.1, DVec2::new(f64::NAN, 0.0)).unwrap_err().to_string().contains("`origin`"));
    }

    #[test]
    fn a_grid_on_a_map_geometry_finds_cells_as_the_map_does() {
        let g = GridGeometry { resolution_m: 0.1, nx: 4, ny: 3, origin_cell: (-7, 5) };
        let values = [0.25; 12];
        let grid = RiskGrid::on_geometry(&values, &g).unwrap();
        for p in [DVec2::new(-0.65, 0.55), DVec2::new(-0.35, 0.75), DVec2::new(-0.7, 0.5), DVec2::new(0.0, 0.0)] {
            assert_eq!(grid.cell_of(p), g.cell_of(p.x, p.y), "{p}");
        }
        let c = CellIndex { ix: 2, iy: 1 };
        assert_eq!(grid.centre_of(c), g.centre_of(c));
        assert_eq!(grid.risk_at(g.centre_of(c)), Some(0.25));
        assert_eq!(grid.risk_at(DVec2::new(10.0, 10.0)), None);
    }
}
