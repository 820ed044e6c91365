//! APF-PF depth perception (Ahmad et al., ACC 2021).
//!
//! In: a depth image (`u16` with a scale or `f32` metres) of a [`PinholeCamera`](crate::camera::PinholeCamera).
//! Out: a belief over where the nearest obstacle probably is — voxels of a 2.5D grid over
//! the image, plus "free" — and the belief-weighted repulsive force in the body frame.
//!
//! [`DepthVoxelGrid`] counts pixels into voxels ([`VoxelCounts`]), [`TransitionModel`] and
//! the observation model are the filter's models, a particle filter or the exact histogram
//! filter ([`FilterMode`](crate::config::FilterMode)) tracks the belief, and
//! [`DepthPerception`] wires them together.

mod alias;
mod filter;
mod grid;
mod observation;
mod perception;
mod transition;

pub use grid::{DepthImage, DepthVoxelGrid, StateId, VoxelCounts, VoxelIndex, DEPTH_SCALE_RANGE_M_PER_UNIT};
pub use perception::{DepthPerception, MostProbableVoxel, PerceptionOutput, StageTimings};
pub use transition::TransitionModel;
