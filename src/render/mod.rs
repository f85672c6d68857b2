//! The forward pipeline's GPU building blocks: prefix sums and the key–value radix sort.

pub mod forward;
pub mod layout;
pub mod scan;
pub mod sort;
pub mod synthetic;
