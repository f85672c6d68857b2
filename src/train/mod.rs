//! Training: the optimiser, its schedules and adaptive density control.

pub mod adam;
pub mod density;
pub mod schedule;
