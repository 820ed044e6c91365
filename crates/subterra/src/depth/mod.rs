//! APF-PF depth perception (Ahmad et al., ACC 2021).
//!
//! In: a depth image (`u16` with a scale or `f32` metres) of a [`PinholeCamera`](crate::camera::PinholeCamera).
//! Out: a belief over where the nearest obstacle probably is — voxels of a 2.5D grid over
//! the image, plus "free" — and the belief-weighted repulsive force in the body frame.
//!
//! [`grid`] counts pixels into voxels, [`transition`] and [`observation`] are the
//! filter's models, [`filter`] holds the particle and exact histogram filters, and
//! [`perception`] wires them into [`DepthPerception`].

mod alias;
pub mod filter;
pub mod grid;
pub mod observation;
pub mod perception;
pub mod transition;

pub use grid::{DepthImage, DepthVoxelGrid, StateId, VoxelCounts, VoxelIndex};
pub use perception::{DepthPerception, MostProbableVoxel, PerceptionOutput, StageTimings};
pub use transition::TransitionModel;
